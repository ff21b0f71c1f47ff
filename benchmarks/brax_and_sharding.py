"""Training throughput on PointLTL0-v0 with GenZ-LTL-style one-subgoal tasks: Brax PPO through
`specrl_jax.brax` against our own PPO on the same task and batch shape, and our PPO with the env
batch sharded over every local device (`env_mesh()`) against the unsharded trainer.

    python benchmarks/brax_and_sharding.py --num-envs 2048 --unroll 20     # a GPU
    python benchmarks/brax_and_sharding.py --num-envs 16 --unroll 8 --updates 2 --brax-evals 3

Env-steps/s of training exclude compilation: ours is the median of 5 timed chunks of `--updates`
updates after a first one; Brax's is its own `training/sps` of the last training epoch (the first includes compilation).
Both use one rollout of every env per update, 2 minibatches and 4 epochs. Writes JSON to `--out`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from importlib.metadata import version
from pathlib import Path

import jax

ROOT = Path(__file__).resolve().parents[1]


def ours(env_id: str, num_envs: int, unroll: int, updates: int, sharded: bool,
         repeats: int = 5) -> float:
    """Env-steps/s of our PPO (GenZ-LTL's method, plain PPO epochs) over `updates` updates, the
    median of `repeats` timed chunks."""
    from specrl_jax.baselines import genz
    from specrl_jax.baselines.ppo import env_mesh, make_train
    from specrl_jax.envs.registry import make

    world, params = make(env_id)
    method = genz.make_method(world, params, "zone")
    config = genz.ppo_config("zone", num_envs=num_envs, num_steps=unroll, num_minibatches=2,
                             update_epochs=4, target_kl=None,
                             total_timesteps=num_envs * unroll * updates)
    trainer = make_train(config, method, env_mesh() if sharded else None)
    runner = jax.jit(trainer.init)(jax.random.key(0))
    chunk = jax.jit(trainer.updates, static_argnums=1)
    runner, _ = jax.block_until_ready(chunk(runner, updates))  # compile and warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        runner, _ = jax.block_until_ready(chunk(runner, updates))
        times.append(time.perf_counter() - start)
    return updates * config.batch_size / sorted(times)[len(times) // 2]


def brax_ppo(env_id: str, num_envs: int, unroll: int, evals: int, updates: int) -> float:
    """Brax's own training env-steps/s of its last epoch, via examples/brax_ppo_point.py."""
    sys.path.insert(0, str(ROOT / "examples"))
    import brax_ppo_point

    steps = num_envs * unroll * updates * (evals - 1)
    rows = brax_ppo_point.main([
        "--env", env_id, "--num-envs", str(num_envs), "--unroll-length", str(unroll),
        "--num-timesteps", str(steps), "--num-evals", str(evals), "--episode-length", "1000",
        "--num-eval-envs", str(num_envs), "--out", "/tmp/brax_and_sharding",
    ])
    return rows[-1]["train_env_steps_per_s"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PointLTL0-v0")
    parser.add_argument("--num-envs", type=int, default=2048)
    parser.add_argument("--unroll", type=int, default=20)
    parser.add_argument("--updates", type=int, default=10, help="updates per timed chunk / epoch")
    parser.add_argument("--brax-evals", type=int, default=3)
    parser.add_argument("--skip", nargs="*", default=(), choices=("brax", "ours", "sharded"))
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/brax_and_sharding.json"))
    args = parser.parse_args()
    record = {"env": args.env, "num_envs": args.num_envs, "unroll": args.unroll,
              "updates": args.updates, "device": jax.devices()[0].device_kind,
              "devices": jax.local_device_count(),
              "versions": {n: version(n) for n in ("jax", "brax", "mujoco-mjx")},
              "date": time.strftime("%Y-%m-%d")}
    if "ours" not in args.skip:
        record["ours_env_steps_per_s"] = ours(args.env, args.num_envs, args.unroll, args.updates,
                                              False)
        print(record, flush=True)
    if "sharded" not in args.skip:
        record["ours_sharded_env_steps_per_s"] = ours(args.env, args.num_envs, args.unroll,
                                                      args.updates, True)
        print(record, flush=True)
    if "brax" not in args.skip:
        record["brax_ppo_env_steps_per_s"] = brax_ppo(args.env, args.num_envs, args.unroll,
                                                      args.brax_evals, args.updates)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(record, indent=1))
    print(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
