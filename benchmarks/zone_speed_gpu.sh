#!/usr/bin/env bash
# Issue 18 on one GPU: CarLTL0 / AntLTL0 env-steps/s in the default MJX-JAX physics before and
# after the contact cap and sensor-free substeps, and the per-stage profile. Each mode fits in
# 4 minutes on one H100 (every call has its own time limit; rows measured before a limit is hit
# are kept in OUT/results.md and OUT/profile_*.json).
#
#   bash benchmarks/zone_speed_gpu.sh throughput OUT   # after, then before (--solver of issue 18's start)
#   bash benchmarks/zone_speed_gpu.sh profile OUT      # zone_profile.py, Car then Ant, batch 16,384
#   bash benchmarks/zone_speed_gpu.sh variants OUT     # after, with the substep loop unrolled twice,
#                                                       # then with XLA's Triton GEMMs for every dot
set -u
MODE=${1:?mode: throughput, profile or variants}
OUT=${2:?output directory}
mkdir -p "$OUT"
T="python benchmarks/env_throughput.py --resets exact --results $OUT/results.md"
BEFORE="max_contacts=0 substep_sensors=True"
case "$MODE" in
  throughput)
    timeout 125 $T --envs CarLTL0-v0 AntLTL0-v0 --batches 65536 --steps 10 --repeats 1
    timeout 110 $T --envs CarLTL0-v0 AntLTL0-v0 --batches 16384 --steps 5 --repeats 1 --solver $BEFORE
    ;;
  profile)
    timeout 95 python benchmarks/zone_profile.py --robots Car --batch 16384 --warm 3 --loops 5 \
      --repeats 2 --out "$OUT/profile_car.json"
    timeout 130 python benchmarks/zone_profile.py --robots Ant --batch 16384 --warm 3 --loops 5 \
      --repeats 2 --out "$OUT/profile_ant.json"
    ;;
  variants)
    timeout 115 $T --envs CarLTL0-v0 AntLTL0-v0 --batches 65536 --steps 10 --repeats 1 --solver unroll=2
    XLA_FLAGS=--xla_gpu_triton_gemm_any=True timeout 115 $T --envs CarLTL0-v0 AntLTL0-v0 \
      --batches 65536 --steps 10 --repeats 1
    ;;
  *) echo "unknown mode $MODE" >&2; exit 2 ;;
esac
