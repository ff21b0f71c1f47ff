#!/usr/bin/env bash
# Reproduction runs on the lent GPU: `bash benchmarks/repro_gpu.sh ENV METHOD MAX_WALL [extra args]`
# trains METHOD on ENV (5 seeds x 15M steps, at most MAX_WALL training seconds), evaluates the
# world's paper suites (5 seeds x 100 episodes) and copies the results, curves and one seed's
# parameters to $OUT. Needs the wheels in .whl (benchmarks/device_prelude.sh). The run directory is
# $REPRO_DIR (default: a new one under /tmp), so two runs can share a machine, one per GPU.
set -u
source benchmarks/device_prelude.sh || exit 1
env_id=$1 method=$2 max_wall=$3
shift 3
nvidia-smi --query-gpu=name --format=csv,noheader
python -c "import jax, flax, mujoco; print('jax', jax.__version__, 'flax', flax.__version__, 'mujoco', mujoco.__version__)"
run=${REPRO_DIR:-$(mktemp -d /tmp/repro.XXXX)}
echo "run directory: $run"
python benchmarks/train_baselines.py --env "$env_id" --methods "$method" --seeds 5 \
  --total-steps 15000000 --episodes 100 --max-wall "$max_wall" --out $run "$@" 2>&1 | tee $OUT/log
tag="$(echo "$env_id" | cut -d- -f1 | tr A-Z a-z)_$method"
cp $run/results.json "$OUT/${tag}_results.json"
cp $run/tables.md "$OUT/${tag}_tables.md"
cp $run/$method/metrics.jsonl "$OUT/${tag}_metrics.jsonl"
cp $run/$method/curve.png "$OUT/${tag}_training_curve.png" 2>/dev/null
cp $run/$method/train_summary.json "$OUT/${tag}_train_summary.json"
python - "$run/$method/params.msgpack" "$OUT/${tag}_params_seed1.msgpack" <<'PY'
import sys
from flax import serialization
import jax
state = serialization.msgpack_restore(open(sys.argv[1], "rb").read())
one = jax.tree.map(lambda x: x[0], state)
open(sys.argv[2], "wb").write(serialization.msgpack_serialize(one))
PY
