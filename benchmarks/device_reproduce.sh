#!/bin/bash
# On the lent GPU machine: `specrl-jax reproduce` against a store there, with its log and the
# cells the store holds brought back under $OUT (cells.tar.gz). The store outlives a call while
# the machine stays warm, so the same command with --max-minutes resumes where the last stopped.
# Left behind: the store's scratch/ (resumable runs; an image cell's checkpoint is tens of MB) and
# any file over KEEP_MB, e.g. GCRL-LTL's seed-1 parameters at 64 x 64 (68 MB), which the package's
# store does not keep. Unpack cells.tar.gz into specrl_jax/benchmark/results.
# Usage: bash benchmarks/device_reproduce.sh REPRODUCE_ARGS...
#   e.g. bash benchmarks/device_reproduce.sh --cells 'PointLTL0Vision-v0/gcrl' --seed-range 1-2 --max-minutes 7
# STORE: the store (default /tmp/store); KEEP_MB: the largest file brought back (default 20; whole MB).
cd "$(dirname "$0")/.." || exit 1
source benchmarks/device_prelude.sh || exit 1
store=${STORE:-/tmp/store}
out=${OUT:?set OUT to the folder whose files come back}
python3 -c "import jax, flax, mujoco; print('jax', jax.__version__, 'flax', flax.__version__, \
'mujoco', mujoco.__version__, jax.devices())"
python3 -m specrl_jax.cli reproduce --store "$store" "$@" 2>&1 | tee "$out/reproduce_$(date +%Y%m%dT%H%M%S).log"
rc=${PIPESTATUS[0]}
if [ -d "$store" ]; then
  (cd "$store" && find . -path ./scratch -prune -o -type f -size -$((${KEEP_MB:-20} * 1024))k -print \
    | tar czf "$out/cells.tar.gz" -T -)
fi
exit "$rc"
