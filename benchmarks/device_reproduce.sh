#!/bin/bash
# On the lent GPU machine: `specrl-jax reproduce` against a store there, with its log and what it
# wrote to the store brought back under $OUT (cells.tar.gz; unpack it into
# specrl_jax/benchmark/results). The store starts as a copy of the package's, so a part of a cell
# (--seed-range 3-5) joins the seeds the package holds; a warm machine keeps it between calls, so
# the same command with --max-minutes resumes where the last one stopped.
# Left behind: the store's scratch/ (resumable runs; an image cell's checkpoint is tens of MB) and
# any file over KEEP_MB, e.g. GCRL-LTL's seed-1 parameters at 64 x 64 (68 MB), which the package's
# store does not keep.
# Usage: bash benchmarks/device_reproduce.sh REPRODUCE_ARGS...
#   e.g. bash benchmarks/device_reproduce.sh --cells 'PointLTL0Vision-v0/gcrl' --seed-range 3-5 \
#          --max-minutes 7
# STORE: the store (default /tmp/store); KEEP_MB: the largest file brought back (default 20, in
# whole MB).
cd "$(dirname "$0")/.." || exit 1
source benchmarks/device_prelude.sh || exit 1
store=${STORE:-/tmp/store}
out=${OUT:?set OUT to the folder whose files come back}
if [ ! -f "$store/.copied" ]; then
  mkdir -p "$store" && cp -r specrl_jax/benchmark/results/. "$store"/ || exit 1
  touch "$store/.copied"
fi
python3 -c "import jax, flax, mujoco; print('jax', jax.__version__, 'flax', flax.__version__, \
'mujoco', mujoco.__version__, jax.devices())"
python3 -m specrl_jax.cli reproduce --store "$store" "$@" 2>&1 \
  | tee "$out/reproduce_$(date +%Y%m%dT%H%M%S).log"
rc=${PIPESTATUS[0]}
(cd "$store" && find . -path ./scratch -prune -o -type f -newer .copied \
  -size -$((${KEEP_MB:-20} * 1024))k -print | tar czf "$out/cells.tar.gz" -T -)
exit "$rc"
