#!/bin/bash
# On the lent GPU machine: `specrl-jax reproduce` against a store there, with its log and what was
# written to the store since it was copied brought back under $OUT (cells.tar.gz; unpack it into
# specrl_jax/benchmark/results). The store starts as a copy of the package's, so a part of a cell
# (--seed-range 3-5) joins the seeds the package holds; a warm machine keeps it between calls, so
# the same command with --max-minutes resumes where the last one stopped, and a call killed
# before packing has its files brought back by the next.
# A cell still training when a machine goes away resumes on the next one: the run directories
# under the store's scratch/ of cells not yet done come back too (scratch.tar.gz), each whole or
# not at all, together at most KEEP_MB (a LiDAR cell's run is a few MB; an image cell's
# checkpoint, tens, stays behind and its cell trains again from the start); unpack it into
# .carry/scratch (emptied first) and carry ".carry" in the next machine's first call, whose store
# then starts from those runs. A call returns files of at most 16 MiB and carries at most 64 MiB
# with the tracked tree (31 MB) and .site (10 MB).
# Left behind, and listed at the end of the log: the scratch/ of cells that are done and any file
# over KEEP_MB, e.g. GCRL-LTL's seed-1 parameters at 64 x 64 (68 MB), which the package's store
# does not keep. Files that the run deleted (a retrained seed 1's parameters and trajectories) are
# listed too: delete them from the package.
# Usage: bash benchmarks/device_reproduce.sh REPRODUCE_ARGS...
#   e.g. bash benchmarks/device_reproduce.sh --cells 'PointLTL0Vision-v0/gcrl' --seed-range 3-5 \
#          --max-minutes 7
# STORE: the store (default /tmp/store; a relative path is under the repository root); KEEP_MB:
# the largest file, and the most run directories, brought back (default and at most 15, in whole
# MB); FRESH=1: copy the package's store again, keeping the store's run directories (after the
# package's store changed on this side); CARRIED: the carried run directories (default
# .carry/scratch).
cd "$(dirname "$0")/.." || exit 1
root=$PWD
source benchmarks/device_prelude.sh || exit 1
store=${STORE:-/tmp/store}
out=${OUT:?set OUT to the folder whose files come back}
case $store in /*) ;; *) store=$root/$store ;; esac
case $out in /*) ;; *) out=$root/$out ;; esac
store=${store%/}
log="$out/reproduce_$(date +%Y%m%dT%H%M%S).log"
# beside the store, so that removing the store keeps them; a call killed while they are there
# leaves them for the next call to put back
kept_runs="$(dirname "$store")/.$(basename "$store").kept_scratch"
if [ -d "$kept_runs" ] && [ -d "$store/scratch" ]; then
  echo "run directories in both $kept_runs and $store/scratch: keep one, then call again" >&2
  exit 1
fi
if [ -n "${FRESH:-}" ]; then
  if [ -d "$store/scratch" ]; then mv "$store/scratch" "$kept_runs" || exit 1; fi
  rm -rf "$store"
fi
if [ ! -f "$store/.copied" ]; then
  mkdir -p "$store" && cp -r specrl_jax/benchmark/results/. "$store"/ || exit 1
  touch "$store/.copied"
fi
if [ -d "$kept_runs" ]; then mv "$kept_runs" "$store/scratch" || exit 1; fi
carried=${CARRIED:-.carry/scratch}
for run in "$carried"/*/; do
  [ -d "$run" ] || continue
  name=$(basename "$run")
  if [ -e "$store/scratch/$name" ]; then
    echo "the store's run directory $name kept (newer than the carried one)" | tee -a "$log"
  else
    part="$store/scratch/.$name.part"
    rm -rf "$part" && mkdir -p "$part" && cp -r "$run". "$part" \
      && mv "$part" "$store/scratch/$name" || exit 1
    echo "resuming from the carried run directory: $name" | tee -a "$log"
  fi
done
python3 -c "import jax, flax, mujoco; print('jax', jax.__version__, 'flax', flax.__version__, \
'mujoco', mujoco.__version__, jax.devices())"
python3 -m specrl_jax.cli reproduce --store "$store" "$@" 2>&1 | tee -a "$log"
rc=${PIPESTATUS[0]}
cd "$store" || exit 1
keep_mb=${KEEP_MB:-15}
case $keep_mb in ''|*[!0-9]*) echo "KEEP_MB is whole MB, 1 to 15; got '$keep_mb'" >&2; exit 1 ;; esac
[ "$keep_mb" -le 15 ] || keep_mb=15  # two archives of up to 16 MiB would not come back
keep_k=$((keep_mb * 1024))
find . -path ./scratch -prune -o -type f -newer .copied -size -"$keep_k"k -print \
  | tar czf "$out/cells.tar.gz" -T -
find . -path ./scratch -prune -o -type f -newer .copied -size +$((keep_k - 1))k -print \
  | sed 's/^/left behind (too large): /' | tee -a "$log"
resumable=$(python3 - "$store" 2>>"$log" <<'EOF'
import sys
from specrl_jax.benchmark import grid
from specrl_jax.benchmark.store import Store
store = Store(sys.argv[1])
for run in sorted((store.root / "scratch").glob("*/")):
    name = grid.cell_name(run.name)
    if name in grid.BY_NAME and store.state(grid.cell(name)) != "done":
        print(run.name)
EOF
) || echo "could not list the resumable run directories (the error is above)" | tee -a "$log"
runs=()
total=0
for name in $resumable; do
  size=$(du -sk --apparent-size "scratch/$name" | cut -f1)
  if [ $((total + size)) -le "$keep_k" ]; then
    runs+=("$name")
    total=$((total + size))
  else
    echo "left behind (${size} kB, over the ${keep_k} kB that come back with ${total} kB" \
      "packed): ./scratch/$name" | tee -a "$log"
  fi
done
if [ ${#runs[@]} -gt 0 ]; then
  if (cd scratch && tar czf "$out/scratch.tar.gz" "${runs[@]}"); then
    printf 'resumable run brought back (scratch.tar.gz): %s\n' "${runs[@]}" | tee -a "$log"
  else
    rm -f "$out/scratch.tar.gz"
    echo "could not pack the resumable run directories: none comes back" | tee -a "$log"
  fi
fi
(cd "$root/specrl_jax/benchmark/results" && find . -type f) | while read -r f; do
  [ -e "$f" ] || echo "deleted by the run: $f"
done | tee -a "$log"
exit "$rc"
