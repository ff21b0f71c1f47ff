#!/bin/bash
# On the lent GPU machine: `specrl-jax reproduce` against a store there, with its log and what was
# written to the store since it was copied brought back under $OUT (cells.tar.gz; unpack it into
# specrl_jax/benchmark/results). The store starts as a copy of the package's, so a part of a cell
# (--seed-range 3-5) joins the seeds the package holds; a warm machine keeps it between calls, so
# the same command with --max-minutes resumes where the last one stopped, and a call killed
# before packing has its files brought back by the next.
# Left behind, and listed at the end of the log: the store's scratch/ (resumable runs; an image
# cell's checkpoint is tens of MB) and any file over KEEP_MB, e.g. GCRL-LTL's seed-1 parameters
# at 64 x 64 (68 MB), which the package's store does not keep. Files that the run deleted (a
# retrained seed 1's parameters and trajectories) are listed too: delete them from the package.
# Usage: bash benchmarks/device_reproduce.sh REPRODUCE_ARGS...
#   e.g. bash benchmarks/device_reproduce.sh --cells 'PointLTL0Vision-v0/gcrl' --seed-range 3-5 \
#          --max-minutes 7
# STORE: the store (default /tmp/store); KEEP_MB: the largest file brought back (default 20, in
# whole MB); FRESH=1: copy the package's store again (after it changed on this side).
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
python3 -c "import jax, flax, mujoco; print('jax', jax.__version__, 'flax', flax.__version__, \
'mujoco', mujoco.__version__, jax.devices())"
python3 -m specrl_jax.cli reproduce --store "$store" "$@" 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
cd "$store" || exit 1
keep_k=$((${KEEP_MB:-20} * 1024))
find . -path ./scratch -prune -o -type f -newer .copied -size -"$keep_k"k -print \
  | tar czf "$out/cells.tar.gz" -T -
find . -path ./scratch -prune -o -type f -newer .copied -size +$((keep_k - 1))k -print \
  | sed 's/^/left behind (too large): /' | tee -a "$log"
(cd "$root/specrl_jax/benchmark/results" && find . -type f) | while read -r f; do
  [ -e "$f" ] || echo "deleted by the run: $f"
done | tee -a "$log"
exit "$rc"
