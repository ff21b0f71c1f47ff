#!/usr/bin/env bash
# Env throughput of one env ID at one batch under several XLA_FLAGS settings, each in its own
# process (XLA reads the flags when its backend starts). The settings: the defaults; while loops
# and conditionals recorded into CUDA graphs (command buffers) too; no command buffers at all.
# env_throughput.py writes the flags into each results header. On a lent GPU:
#
#   source benchmarks/device_prelude.sh && bash benchmarks/xla_flag_sweep.sh ENV_ID BATCH RESETS
set -u
env_id=$1 batch=$2 resets=${3:-exact}
settings=(
  ""
  "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL --xla_gpu_graph_min_graph_size=1"
  "--xla_gpu_enable_command_buffer="
)
for flags in "${settings[@]}"; do
  echo "== $env_id batch $batch resets $resets XLA_FLAGS=[$flags]"
  XLA_FLAGS="$flags" timeout "${SWEEP_PART_SECONDS:-150}" python benchmarks/env_throughput.py \
    --envs "$env_id" --batches "$batch" --resets "$resets" --steps "${SWEEP_STEPS:-10}" --repeats 3 \
    --bank-size 4096 --results "$OUT/sweep.md"
done
