#!/usr/bin/env bash
# The arm world on one lent GPU, within 540 s, compile included: env throughput of
# PandaLTLReach0Joints-v0, then PandaLTLReach1Joints-v0, with auto-reset from a layout bank (batch
# 32,768, the issue-13 command); arm_checks.py's tracking gains (256 arms x 300 steps) and NaN
# check (4,096 arms x 1,000 saturated steps, both modes); then env throughput with exact resets
# (batch 16,384). If the first throughput part runs out of time, arm_checks.py times the compile of
# each piece of the step at that batch instead (`--parts compile`, JSON in $OUT/arm_compile.json).
#
# Each part has its own time limit, cut further so that the whole script ends by ARM_GPU_SECONDS
# (default 530 s); a part with under 20 s left is skipped. Parts share JAX's persistent compilation
# cache (the layout bank's program, the resets). Not yet measured on a GPU: on a 2-core CPU
# (batch 8, load ~3) the compile of each throughput program fell from 43 s / 51 s (modes 0 / 1) to
# 22.5 s / 22.6 s and its StableHLO from 34k / 44k to 15k / 16k operations, so each throughput part
# is expected to take 60-120 s here (it timed out at 140 s before). Writes $OUT/results.md,
# $OUT/arm_checks_gains.json, $OUT/arm_checks.json and $OUT/log:
#
#   source benchmarks/device_prelude.sh && bash benchmarks/arm_gpu.sh 2>&1 | tee $OUT/log
set -u
results="$OUT/results.md"
deadline=${ARM_GPU_SECONDS:-530}
export JAX_COMPILATION_CACHE_DIR="${JAX_COMPILATION_CACHE_DIR:-/tmp/jax_cache}"
code=0
part() {  # part LIMIT SCRIPT ARGS...: python SCRIPT ARGS within LIMIT s and the time left; sets $code
  local left=$((deadline - SECONDS))
  local limit=$(($1 < left ? $1 : left))
  shift
  if [ "$limit" -lt 20 ]; then
    echo "== skipped, ${left}s left: $*"
    code=125
    return
  fi
  echo "== $(date +%T) at ${SECONDS}s (limit ${limit}s) $*"
  timeout "$limit" python "$@"
  code=$?  # 124: the part hit its time limit
  echo "== $(date +%T) exit $code"
}
SECONDS=0
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
python -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())"
bank=(--resets bank --batches 32768 --steps 50 --repeats 2 --bank-size 4096 --results "$results")
part 150 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 "${bank[@]}"
if [ "$code" -eq 124 ]; then
  part 150 benchmarks/arm_checks.py --parts compile --compile-batch 32768 \
    --pieces kinematics observe_mode0 substep physics_step step_mode0 --out "$OUT/arm_compile.json"
fi
part 150 benchmarks/env_throughput.py --envs PandaLTLReach1Joints-v0 "${bank[@]}"
part 60 benchmarks/arm_checks.py --parts gains --gain-batch 256 --gain-steps 300 \
  --out "$OUT/arm_checks_gains.json"
part 170 benchmarks/arm_checks.py --parts nan --batch 4096 --steps 1000 --bank-size 4096 \
  --out "$OUT/arm_checks.json"
part 120 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 PandaLTLReach1Joints-v0 \
  --resets exact --batches 16384 --steps 50 --repeats 2 --results "$results"
echo "== done at ${SECONDS}s"
