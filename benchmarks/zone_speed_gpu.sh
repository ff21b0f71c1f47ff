#!/usr/bin/env bash
# Issue 18 on one GPU: CarLTL0 / AntLTL0 env-steps/s in the default MJX-JAX physics (exact
# auto-reset) under one setting per mode, and the per-stage profile. Each mode fits in 4 minutes
# on one H100 (each call has its own limit, sized from the H100 compile times of the first run:
# CarLTL0 46 s, AntLTL0 76 s); rows measured before a limit is hit stay in OUT/results.md and
# OUT/profile_*.json. The Ant goes first.
#
#   bash benchmarks/zone_speed_gpu.sh throughput OUT      # the defaults
#   bash benchmarks/zone_speed_gpu.sh before OUT          # the settings before issue 18
#   bash benchmarks/zone_speed_gpu.sh cholesky OUT        # defaults + Solver small_cholesky
#   bash benchmarks/zone_speed_gpu.sh triton OUT          # defaults, XLA's Triton GEMMs for every dot
#   bash benchmarks/zone_speed_gpu.sh profile OUT         # zone_profile.py, batch 16,384
#   bash benchmarks/zone_speed_gpu.sh profile-cholesky OUT
set -u
MODE=${1:?mode: throughput, before, cholesky, triton, profile or profile-cholesky}
OUT=${2:?output directory}
mkdir -p "$OUT"
T="python benchmarks/env_throughput.py --resets exact --steps 5 --repeats 1 --results $OUT/results.md"
P="python benchmarks/zone_profile.py --batch 16384 --warm 3 --loops 5 --repeats 3"
BEFORE="max_contacts=0 substep_sensors=True"
pair() {  # pair LIMIT_ANT LIMIT_CAR [env_throughput options]
  local ant=$1 car=$2
  shift 2
  timeout "$ant" $T --envs AntLTL0-v0 --batches 16384 "$@"
  timeout "$car" $T --envs CarLTL0-v0 --batches 65536 "$@"
}
case "$MODE" in
  throughput) pair 110 80 ;;
  before) pair 120 80 --solver $BEFORE ;;
  cholesky) pair 300 90 --solver small_cholesky=True ;;  # its Ant compiles past 130 s on an H200
  triton) (export XLA_FLAGS=--xla_gpu_triton_gemm_any=True; pair 120 85) ;;
  profile)
    timeout 145 $P --robots Ant --out "$OUT/profile_ant.json"
    timeout 90 $P --robots Car --out "$OUT/profile_car.json"
    ;;
  profile-cholesky)
    timeout 145 $P --robots Ant --solver small_cholesky=True --out "$OUT/profile_ant_cholesky.json"
    timeout 90 $P --robots Car --solver small_cholesky=True --out "$OUT/profile_car_cholesky.json"
    ;;
  *) echo "unknown mode $MODE" >&2; exit 2 ;;
esac
