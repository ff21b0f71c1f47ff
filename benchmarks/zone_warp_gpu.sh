#!/usr/bin/env bash
# Zone robots with MuJoCo Warp (through MJX) on the lent GPU: env throughput with exact auto-reset,
# then MJX-Warp against MuJoCo C. Needs warp-lang and the project on PYTHONPATH; writes $OUT/results.md
# and $OUT/log. Each measurement has its own time limit, so one that hangs does not stop the rest.
set -u
results="$OUT/results.md"
measure() {
  local limit=$1
  shift
  echo "== $(date +%T) $*"
  timeout "$limit" python "$@" --results "$results" 2>&1 | grep -v '^Module \|^Warp \|^   '
  echo "== exit ${PIPESTATUS[0]}"
}
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
python -c "import jax, warp, mujoco; print('jax', jax.__version__, 'warp', warp.__version__, 'mujoco', mujoco.__version__)"
if [ "${1:-1}" = 5 ]; then  # session 17: the default physics ("auto": Warp for Car and Ant on one GPU)
  measure 240 benchmarks/env_throughput.py --envs CarLTL0-v0 AntLTL0-v0 --batches 65536 262144 --resets exact --steps 10 --repeats 2
  measure 120 benchmarks/zone_physics.py --physics warp --robots Car Ant --steps 30 --seeds 3
  measure 200 benchmarks/physics_determinism.py --envs CarLTL0-v0 AntLTL0-v0 --physics jax warp --batch 4096 --steps 50
elif [ "$1" = 6 ]; then  # session 17: GenZ-LTL trains on Car (both backends) and Ant (Warp), 2M steps each
  for run in "CarLTL0-v0 auto" "CarLTL0-v0 jax" "AntLTL0-v0 auto"; do
    set -- $run
    echo "== $(date +%T) train genz $1 physics=$2"
    timeout 200 python -m specrl_jax.cli train --method genz --env "$1" --env-option "physics=$2" \
      --total-steps 2000000 --out "/tmp/train_$1_$2" --restart 2>&1 | grep -v '^Module \|^Warp \|^   ' | tail -4
    cp "/tmp/train_$1_$2/train_summary.json" "$OUT/train_$1_$2.json" 2>/dev/null
  done
elif [ "$1" = 1 ]; then
  measure 150 benchmarks/env_throughput.py --envs CarLTL0-v0 --physics warp --batches 65536 262144 --resets exact --steps 20 --repeats 2
  measure 110 benchmarks/env_throughput.py --envs AntLTL0-v0 --physics warp --batches 65536 --resets exact --steps 10 --repeats 2
  measure 80 benchmarks/zone_physics.py --physics warp --robots Car Ant --steps 30 --seeds 2
  measure 60 benchmarks/env_throughput.py --envs PointLTL0-v0 --physics warp --batches 262144 --resets exact --steps 20 --repeats 2
  measure 60 benchmarks/env_throughput.py --envs AntLTL0-v0 --physics warp --batches 262144 --resets exact --steps 10 --repeats 2
elif [ "$1" = 4 ]; then  # session 3: the Car from its resting height, line-search cap 4, Warp and MJX-JAX
  measure 150 benchmarks/env_throughput.py --envs CarLTL0-v0 --physics warp --batches 65536 262144 --resets exact --steps 20 --repeats 2
  measure 150 benchmarks/env_throughput.py --envs AntLTL0-v0 --physics warp --batches 65536 262144 --resets exact --steps 10 --repeats 2
  measure 100 benchmarks/zone_physics.py --physics warp --robots Car Ant --steps 30 --seeds 3
  measure 120 benchmarks/env_throughput.py --envs CarLTL0-v0 --batches 16384 65536 --resets exact --steps 10 --repeats 2
elif [ "$1" = 3 ]; then  # third session: line-search cap 4 (C: no change, see docs/fidelity.md), physics only
  measure 80 benchmarks/zone_physics.py --robots Car --steps 0 --batches 65536 --bench-steps 10
  measure 80 benchmarks/zone_physics.py --robots Car --steps 0 --batches 65536 --bench-steps 10 --solver 10 4 6
  measure 100 benchmarks/zone_physics.py --robots Ant --steps 0 --batches 16384 --bench-steps 5
  measure 100 benchmarks/zone_physics.py --robots Ant --steps 0 --batches 16384 --bench-steps 5 --solver 8 4 6
  measure 50 benchmarks/zone_physics.py --physics warp --robots Car --steps 0 --batches 65536 --bench-steps 10 --solver 10 4 6
  measure 50 benchmarks/zone_physics.py --physics warp --robots Ant --steps 0 --batches 65536 --bench-steps 10 --solver 8 4 6
  measure 60 benchmarks/zone_physics.py --physics warp --robots Car Ant --steps 0 --batches 65536 --bench-steps 10
else  # second session: layout banks (MJX-JAX), and the Warp rows the first one missed
  measure 200 benchmarks/env_throughput.py --envs PointLTL2-v0 PointLTL1-v0 PointLTL0-v0 --resets bank --batches 65536 262144 --steps 20 --repeats 2 --bank-size 65536
  measure 150 benchmarks/env_throughput.py --envs AntLTL0-v0 --physics warp --batches 262144 --resets exact --steps 10 --repeats 2
  measure 90 benchmarks/env_throughput.py --envs CarLTL0-v0 AntLTL0-v0 --physics warp --batches 65536 --resets off --steps 10 --repeats 2
fi
