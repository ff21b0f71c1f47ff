#!/usr/bin/env bash
# The arm world on one lent GPU, within 540 s, compile included. On the H100 (commit b3c3c1e) the
# env step compiled in 10-15 s but ran at about 8,200 env-steps/s (4,096 arms), so the parts are
# sized by runtime: env throughput of PandaLTLReach0Joints-v0, then PandaLTLReach1Joints-v0, with
# auto-reset from a layout bank (batches 4,096 and 32,768, 5 steps a call); arm_checks.py's
# solver-iterations part (the physics step with MJX's Newton solver at MuJoCo's 100 iterations
# and tolerance 1e-8, capped at 10 (the model's) and 5, and at tolerance 1e-5: time per step, the
# slowest arm's Newton iterations per substep, and whether one step from 40,960 visited states
# changes; the line-search part, `--parts linesearch`, was measured before); the NaN check
# (4,096 arms x 100 saturated steps per mode; the 1,000 steps take ~8 minutes at this
# speed); the tracking gains (256 arms x 300 steps); env throughput with exact resets (4,096
# arms) if time is left. If the first throughput part runs out of time, arm_checks.py times the
# compile of each piece of the step instead (`--parts compile`, $OUT/arm_compile.json).
#
# Each part has its own time limit, cut further so that the whole script ends by ARM_GPU_SECONDS
# (default 530 s); a part with under 20 s left is skipped. Parts share JAX's persistent
# compilation cache (the layout bank's program, the resets). Writes $OUT/results.md (throughput
# rows), $OUT/arm_iterations.json, $OUT/arm_checks.json, $OUT/arm_checks_gains.json, $OUT/log:
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
bank=(--resets bank --batches 4096 32768 --steps 5 --repeats 2 --bank-size 4096 --results "$results")
part 120 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 "${bank[@]}"
if [ "$code" -eq 124 ]; then
  part 100 benchmarks/arm_checks.py --parts compile --compile-batch 32768 \
    --pieces kinematics observe_mode0 substep physics_step step_mode0 --out "$OUT/arm_compile.json"
fi
part 120 benchmarks/env_throughput.py --envs PandaLTLReach1Joints-v0 "${bank[@]}"
part 180 benchmarks/arm_checks.py --parts iterations --ls-batch 4096 --ls-steps 10 \
  --iterations 10 5 --tolerances 1e-5 --out "$OUT/arm_iterations.json"
part 130 benchmarks/arm_checks.py --parts nan --batch 4096 --steps 100 --bank-size 4096 \
  --out "$OUT/arm_checks.json"
part 60 benchmarks/arm_checks.py --parts gains --gain-batch 256 --gain-steps 300 \
  --out "$OUT/arm_checks_gains.json"
part 60 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 PandaLTLReach1Joints-v0 \
  --resets exact --batches 4096 --steps 5 --repeats 2 --results "$results"
echo "== done at ${SECONDS}s"
