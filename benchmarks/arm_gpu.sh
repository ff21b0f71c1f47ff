#!/usr/bin/env bash
# The arm world on one lent GPU, within ARM_GPU_SECONDS (default 560 s), compile included. With the
# gated collision and solve the env step compiles in about 42 s per batch size on an H200
# (session 16), so the parts are: env throughput of PandaLTLReach0Joints-v0 (batches 65,536 and
# 262,144: the headline figure's), then PandaLTLReach1Joints-v0 (65,536 and 131,072; on an H100's
# 80 GB use 32,768: 65,536 ran out of its memory in session 14), with auto-reset from a layout
# bank (5 steps a call);
# where a substep's time goes (`arm_stages.py`, 4,096 arms at states a uniform rollout reaches);
# the NaN check (4,096 arms x 100 saturated steps per mode; the 1,000 steps take about
# 3 minutes a mode, run them apart); the tracking gains (256 arms x 300 steps) if time is left.
# arm_checks.py's `--parts iterations` and `--parts capacity` time the solver's settings, the
# gating's sub-batch sizes and the solve's pair count when needed.
#
# Each part has its own time limit, cut further so that the whole script ends by ARM_GPU_SECONDS;
# a part with under 20 s left is skipped. Parts share JAX's persistent compilation cache. Writes
# $OUT/results.md (throughput rows), $OUT/arm_stages.json, $OUT/arm_checks.json,
# $OUT/arm_checks_gains.json, $OUT/log:
#
#   source benchmarks/device_prelude.sh && bash benchmarks/arm_gpu.sh 2>&1 | tee $OUT/log
set -u
results="$OUT/results.md"
deadline=${ARM_GPU_SECONDS:-560}
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
bank=(--resets bank --steps 5 --repeats 2 --bank-size 4096 --results "$results")
part 200 benchmarks/env_throughput.py --envs PandaLTLReach0Joints-v0 --batches 65536 262144 "${bank[@]}"
part 150 benchmarks/env_throughput.py --envs PandaLTLReach1Joints-v0 --batches 65536 131072 "${bank[@]}"
part 140 benchmarks/arm_stages.py --batch 4096 --steps 30 --out "$OUT/arm_stages.json"
part 200 benchmarks/arm_checks.py --parts nan --batch 4096 --steps 100 --bank-size 4096 \
  --out "$OUT/arm_checks.json"
part 60 benchmarks/arm_checks.py --parts gains --gain-batch 256 --gain-steps 300 \
  --out "$OUT/arm_checks_gains.json"
echo "== done at ${SECONDS}s"
