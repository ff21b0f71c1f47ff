#!/usr/bin/env bash
# Task-loop figures on the lent GPU: the task layer's overhead on auto-resetting Letter and Point
# steps (batch 65,536), one-seed GenZ-LTL training throughput on PointLTL0-v0, and short end-to-end
# training of both methods on CarLTL0-v0 and AntLTL0-v0. Logs to $OUT.
set -u
source benchmarks/device_prelude.sh || exit 1
nvidia-smi --query-gpu=name --format=csv,noheader
timeout 150 python benchmarks/task_overhead.py --batch 65536 --steps 50 --repeats 7 2>&1 | tee $OUT/overhead.log
timeout 150 python benchmarks/train_baselines.py --env PointLTL0-v0 --methods genz --seeds 1 \
  --total-steps 5242880 --epochs 10 --no-eval --chunk 10 --out /tmp/one 2>&1 | tail -3 | tee $OUT/one_seed.log
for env_id in CarLTL0-v0 AntLTL0-v0; do
  timeout 150 python benchmarks/train_baselines.py --env $env_id --methods genz deepltl --seeds 1 \
    --total-steps 196608 --epochs 10 --no-eval --chunk 3 --out /tmp/$env_id 2>&1 | grep -E "^update|Error|error" | tee -a $OUT/robots.log
done
