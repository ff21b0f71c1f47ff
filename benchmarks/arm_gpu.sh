#!/usr/bin/env bash
# The arm world on one lent GPU (about 4 minutes): env throughput of PandaLTLReach0Joints-v0 and
# PandaLTLReach1Joints-v0 with auto-reset from a layout bank, arm_checks.py (NaN check at 4,096
# arms x 1,000 saturated steps, tracking gains at 256 arms x 300 steps), then env throughput with
# exact resets. Parts share JAX's persistent compilation cache (the layout bank's program). Writes $OUT/results.md (throughput rows), $OUT/arm_checks.json and $OUT/log. Each part
# has its own time limit, so one that is slow does not eat the others; every part prints and
# writes as it goes.
#
#   source benchmarks/device_prelude.sh; bash benchmarks/arm_gpu.sh 2>&1 | tee $OUT/log
set -u
results="$OUT/results.md"
part() {
  local limit=$1
  shift
  echo "== $(date +%T) (limit ${limit}s) $*"
  timeout "$limit" python "$@"
  local code=$?  # 124: the part hit its time limit
  echo "== $(date +%T) exit $code"
}
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
python -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())"
export JAX_COMPILATION_CACHE_DIR="${JAX_COMPILATION_CACHE_DIR:-/tmp/jax_cache}"
part 80 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 PandaLTLReach1Joints-v0 \
  --resets bank --batches 32768 --steps 50 --repeats 2 --bank-size 4096 --results "$results"
part 70 benchmarks/arm_checks.py --parts nan --batch 4096 --steps 1000 --bank-size 4096 \
  --out "$OUT/arm_checks.json"
part 40 benchmarks/arm_checks.py --parts gains --gain-batch 256 --gain-steps 300 \
  --out "$OUT/arm_checks_gains.json"
part 45 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 PandaLTLReach1Joints-v0 \
  --resets exact --batches 16384 --steps 50 --repeats 2 --results "$results"
