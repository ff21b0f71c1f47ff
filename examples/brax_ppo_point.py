"""Brax PPO on PointLTL0-v0 with GenZ-LTL-style one-subgoal tasks, through `specrl_jax.brax`.

The task loop draws a subgoal (reach one colour, avoid up to three others) at every reset and a
fresh one each time it is reached (GenZ-LTL's continual source); the reward is the loop's: +1 per
reached subgoal, -1 on entering an avoided zone, which ends the episode. The success rate is
GenZ-LTL's: reached subgoals over subgoals that ended (reached, violated or timed out), here from
Brax's evaluation episodes, each of which ends once.

    python examples/brax_ppo_point.py     # on a GPU 20M steps, 2,048 envs; on a CPU 32,768, 16
    python examples/brax_ppo_point.py --num-envs 4 --unroll-length 4 --num-timesteps 64 \\
        --num-evals 2 --episode-length 8  # a few iterations on a CPU (minutes, mostly compiling)

Writes `<out>/brax_ppo_point.json`: per evaluation the env steps, wall seconds, success rate,
violations and reward per episode, and the env-steps/s of training between evaluations.
Needs the `brax` extra: pip install 'specrl_jax[brax]'.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax

#: defaults by device kind: the GPU's scale, or minutes on a CPU
DEFAULTS = {"gpu": {"num_timesteps": 20_000_000, "num_envs": 2048, "num_evals": 10},
            "cpu": {"num_timesteps": 32_768, "num_envs": 16, "num_evals": 2}}


def build_env(env_id: str = "PointLTL0-v0") -> Any:
    """The world joined with GenZ-LTL's continual subgoal source and reduced observation."""
    from specrl_jax.baselines import genz
    from specrl_jax.brax import BraxTaskEnv
    from specrl_jax.envs.registry import make

    world, params = make(env_id)
    method = genz.make_method(world, params, "zone")
    return BraxTaskEnv(method.env.task, method.env.params)


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PointLTL0-v0")
    parser.add_argument("--num-timesteps", type=int, default=None,
                        help="default 20M on an accelerator, 32,768 on a CPU")
    parser.add_argument("--num-envs", type=int, default=None,
                        help="default 2,048 on an accelerator, 16 on a CPU")
    parser.add_argument("--unroll-length", type=int, default=20)
    parser.add_argument("--batch-size", type=int, default=None, help="default: num_envs / 2")
    parser.add_argument("--num-minibatches", type=int, default=None,
                        help="default: 2 (one unroll of every env per update)")
    parser.add_argument("--num-updates-per-batch", type=int, default=4)
    parser.add_argument("--episode-length", type=int, default=1000)
    parser.add_argument("--num-evals", type=int, default=None,
                        help="default 10 on an accelerator, 2 on a CPU")
    parser.add_argument("--num-eval-envs", type=int, default=None, help="default: num_envs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/brax_ppo_point")
    args = parser.parse_args(argv)
    kind = "cpu" if jax.devices()[0].platform == "cpu" else "gpu"
    for name, value in DEFAULTS[kind].items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    return args


def main(argv: Sequence[str] | None = None) -> list[dict[str, float]]:
    """Train; returns one row per evaluation (also written as JSON)."""
    from brax.training.agents.ppo import train as ppo

    from specrl_jax.brax import wrap_for_training

    args = parse(argv)
    env = build_env(args.env)
    batch_size = args.batch_size or max(1, args.num_envs // 2)
    num_minibatches = args.num_minibatches or max(1, args.num_envs // batch_size)
    rows: list[dict[str, float]] = []
    start = time.perf_counter()

    def progress(step: int, metrics: dict[str, Any]) -> None:
        reaches = float(metrics["eval/episode_reaches"])
        row = {
            "env_steps": int(step),
            "wall_s": time.perf_counter() - start,
            "success_rate": reaches / (reaches + 1.0),  # each evaluation episode ends once
            "reaches_per_episode": reaches,
            "violations_per_episode": float(metrics["eval/episode_violations"]),
            "reward_per_episode": float(metrics["eval/episode_reward"]),
            "train_env_steps_per_s": float(metrics.get("training/sps", 0.0)),
        }
        rows.append(row)
        print("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                        for k, v in row.items()), flush=True)

    train = functools.partial(
        ppo.train, num_timesteps=args.num_timesteps, num_envs=args.num_envs,
        episode_length=args.episode_length, wrap_env_fn=wrap_for_training,
        unroll_length=args.unroll_length, batch_size=batch_size,
        num_minibatches=num_minibatches, num_updates_per_batch=args.num_updates_per_batch,
        discounting=0.99, learning_rate=3e-4, entropy_cost=1e-3, normalize_observations=True,
        reward_scaling=1.0, num_evals=args.num_evals,
        num_eval_envs=args.num_eval_envs or args.num_envs, seed=args.seed, progress_fn=progress,
    )
    train(env)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record = {"env": args.env, "args": vars(args), "device": jax.devices()[0].device_kind,
              "versions": _versions(), "evals": rows}
    (out / "brax_ppo_point.json").write_text(json.dumps(record, indent=1))
    return rows


def _versions() -> dict[str, str]:
    from importlib.metadata import version

    return {name: version(name) for name in ("jax", "brax", "mujoco-mjx", "specrl_jax")}


if __name__ == "__main__":
    main()
