#!/usr/bin/env bash
# Issue 18 on one GPU: CarLTL0 / AntLTL0 env-steps/s in the default MJX-JAX physics before and
# after the contact cap and sensor-free substeps, and the per-stage profile. Each mode fits in
# 4 minutes on one H100 (every call has its own time limit; rows measured before a limit is hit
# are kept in OUT/results.md and OUT/profile_*.json).
#
#   bash benchmarks/zone_speed_gpu.sh throughput OUT   # after, then before (--solver of issue 18's start)
#   bash benchmarks/zone_speed_gpu.sh profile OUT      # zone_profile.py, Ant then Car, batch 16,384
#   bash benchmarks/zone_speed_gpu.sh profile-before OUT   # the same with the settings before
#   bash benchmarks/zone_speed_gpu.sh variants OUT     # after, with the substep loop unrolled twice,
#                                                       # then with XLA's Triton GEMMs for every dot
#   bash benchmarks/zone_speed_gpu.sh cholesky OUT     # after, with the written-out Cholesky
#                                                       # (Solver small_cholesky), and its Ant profile
set -u
MODE=${1:?mode: throughput, profile, profile-before, variants or cholesky}
OUT=${2:?output directory}
mkdir -p "$OUT"
T="python benchmarks/env_throughput.py --resets exact --results $OUT/results.md"
BEFORE="max_contacts=0 substep_sensors=True"
P="python benchmarks/zone_profile.py --batch 16384 --warm 3 --loops 5 --repeats 3"
case "$MODE" in
  throughput)
    timeout 120 $T --envs CarLTL0-v0 AntLTL0-v0 --batches 65536 --steps 5 --repeats 1
    timeout 115 $T --envs AntLTL0-v0 CarLTL0-v0 --batches 16384 --steps 5 --repeats 1 --solver $BEFORE
    ;;
  profile)
    timeout 130 $P --robots Ant --out "$OUT/profile_ant.json"
    timeout 100 $P --robots Car --out "$OUT/profile_car.json"
    ;;
  profile-before)
    timeout 130 $P --robots Ant --solver $BEFORE --out "$OUT/profile_ant_before.json"
    timeout 100 $P --robots Car --solver $BEFORE --out "$OUT/profile_car_before.json"
    ;;
  variants)
    timeout 115 $T --envs CarLTL0-v0 AntLTL0-v0 --batches 65536 --steps 5 --repeats 1 --solver unroll=2
    XLA_FLAGS=--xla_gpu_triton_gemm_any=True timeout 115 $T --envs CarLTL0-v0 AntLTL0-v0 \
      --batches 65536 --steps 5 --repeats 1
    ;;
  cholesky)
    timeout 120 $T --envs CarLTL0-v0 AntLTL0-v0 --batches 65536 --steps 5 --repeats 1 \
      --solver small_cholesky=True
    timeout 110 $P --robots Ant --solver small_cholesky=True --out "$OUT/profile_ant_cholesky.json"
    ;;
  *) echo "unknown mode $MODE" >&2; exit 2 ;;
esac
