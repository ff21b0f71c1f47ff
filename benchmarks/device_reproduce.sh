#!/bin/bash
# On the lent GPU machine: `specrl-jax reproduce` against a store there, with its log and what was
# written to the store since it was copied brought back under $OUT (cells.tar.gz; unpack it into
# specrl_jax/benchmark/results). The store starts as a copy of the package's, so a part of a cell
# (--seed-range 3-5) joins the seeds the package holds; a warm machine keeps it between calls, so
# the same command with --max-minutes resumes where the last one stopped, and a call killed
# before packing has its files brought back by the next.
# A cell still training when a machine goes away resumes on the next one: the run directories
# under the store's scratch/ of cells not yet done come back too (scratch.tar.gz, its files up to
# KEEP_MB; a LiDAR world's checkpoint is a few MB, an image world's tens); unpack it into
# .carry/scratch (emptied first) and carry ".carry" in the next machine's first call, whose store
# then starts from those runs.
# Left behind, and listed at the end of the log: the scratch/ of cells that are done and any file
# over KEEP_MB, e.g. GCRL-LTL's seed-1 parameters at 64 x 64 (68 MB), which the package's store
# does not keep. Files that the run deleted (a retrained seed 1's parameters and trajectories) are
# listed too: delete them from the package.
# Usage: bash benchmarks/device_reproduce.sh REPRODUCE_ARGS...
#   e.g. bash benchmarks/device_reproduce.sh --cells 'PointLTL0Vision-v0/gcrl' --seed-range 3-5 \
#          --max-minutes 7
# STORE: the store (default /tmp/store); KEEP_MB: the largest file brought back (default 20, in
# whole MB); FRESH=1: copy the package's store again (after it changed on this side); CARRIED:
# the carried run directories (default .carry/scratch).
cd "$(dirname "$0")/.." || exit 1
root=$PWD
source benchmarks/device_prelude.sh || exit 1
store=${STORE:-/tmp/store}
out=${OUT:?set OUT to the folder whose files come back}
log="$out/reproduce_$(date +%Y%m%dT%H%M%S).log"
if [ -n "${FRESH:-}" ]; then
  rm -rf "$store"
fi
if [ ! -f "$store/.copied" ]; then
  mkdir -p "$store" && cp -r specrl_jax/benchmark/results/. "$store"/ || exit 1
  touch "$store/.copied"
fi
carried=${CARRIED:-.carry/scratch}
for run in "$carried"/*/; do
  [ -d "$run" ] || continue
  name=$(basename "$run")
  if [ ! -e "$store/scratch/$name" ]; then
    mkdir -p "$store/scratch" && cp -r "$run" "$store/scratch/$name" || exit 1
    echo "resuming from the carried run directory: $name" | tee -a "$log"
  fi
done
python3 -c "import jax, flax, mujoco; print('jax', jax.__version__, 'flax', flax.__version__, \
'mujoco', mujoco.__version__, jax.devices())"
python3 -m specrl_jax.cli reproduce --store "$store" "$@" 2>&1 | tee -a "$log"
rc=${PIPESTATUS[0]}
cd "$store" || exit 1
keep_k=$((${KEEP_MB:-20} * 1024))
find . -path ./scratch -prune -o -type f -newer .copied -size -"$keep_k"k -print \
  | tar czf "$out/cells.tar.gz" -T -
find . -path ./scratch -prune -o -type f -newer .copied -size +$((keep_k - 1))k -print \
  | sed 's/^/left behind (too large): /' | tee -a "$log"
resumable=$(python3 - "$store" <<'EOF'
import sys
from specrl_jax.benchmark import grid
from specrl_jax.benchmark.store import Store
store = Store(sys.argv[1])
for run in sorted((store.root / "scratch").glob("*/")):
    name = grid.cell_name(run.name)
    if name in grid.BY_NAME and store.state(grid.cell(name)) != "done":
        print(run.name)
EOF
)
if [ -n "$resumable" ]; then
  (cd scratch && find $resumable -type f -size -"$keep_k"k -print \
    | tar czf "$out/scratch.tar.gz" -T -)
  (cd scratch && find $resumable -type f -size +$((keep_k - 1))k -print) \
    | sed 's|^|left behind (too large): ./scratch/|' | tee -a "$log"
  echo "$resumable" | sed 's/^/resumable run brought back (scratch.tar.gz): /' | tee -a "$log"
fi
(cd "$root/specrl_jax/benchmark/results" && find . -type f) | while read -r f; do
  [ -e "$f" ] || echo "deleted by the run: $f"
done | tee -a "$log"
exit "$rc"
