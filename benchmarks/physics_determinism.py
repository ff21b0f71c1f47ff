"""Whether a Zone world's batched rollout repeats bit for bit: the same start and key, run twice.

Each env is stepped `--steps` times at `--batch` worlds with random actions and exact auto-reset
(env_throughput's rollout), twice from copies of one state with one key; the row reports how many
state elements differ between the two runs and by how much at most. MuJoCo Warp sums contact
forces with atomic adds on a GPU, so its runs may differ in the last bits where MJX-JAX's
repeat exactly (warp-lang 1.19's deterministic atomics, `warp.config.deterministic`, cannot
compile MuJoCo Warp's kernels: `smooth._qLD_acc` reads an array it also updates atomically).
Results are appended to docs/results.md (or --results).

    python benchmarks/physics_determinism.py --envs CarLTL0-v0 AntLTL0-v0 --physics jax warp
"""

from __future__ import annotations

import argparse
import datetime
import os
import shlex
import sys

import jax
import jax.numpy as jnp
import numpy as np
from env_throughput import append, device_name, make_rollout

import specrl_jax
from specrl_jax.envs.wrappers import batch


def compare(env_id: str, physics: str, num_envs: int, num_steps: int) -> dict:
    env, params = specrl_jax.make(env_id, physics=physics)
    batched = batch(env, num_envs)
    key_reset, key_run = jax.random.split(jax.random.key(0))
    _, start = jax.jit(batched.reset)(key_reset, params)
    rollout = make_rollout(batched, params, num_steps)
    runs = [jax.device_get(rollout(key_run, jax.tree.map(jnp.copy, start))) for _ in range(2)]
    (state_a, sum_a), (state_b, sum_b) = runs
    leaves_a, leaves_b = jax.tree.leaves(state_a), jax.tree.leaves(state_b)
    differing = sum(int(np.sum(np.asarray(a) != np.asarray(b))) for a, b in zip(leaves_a, leaves_b))
    max_diff = max(
        float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)), initial=0.0))
        for a, b in zip(leaves_a, leaves_b) if np.issubdtype(np.asarray(a).dtype, np.number)
    )
    return {
        "env": env_id, "physics": env.physics.backend, "batch": num_envs, "steps": num_steps,
        "elements": sum(np.asarray(a).size for a in leaves_a), "differing": differing,
        "max_diff": max_diff, "checksums_equal": bool(sum_a == sum_b),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["CarLTL0-v0", "AntLTL0-v0"])
    parser.add_argument("--physics", nargs="+", choices=["auto", "jax", "warp"],
                        default=["jax", "warp"])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--results", default="docs/results.md")
    args = parser.parse_args()
    flags = os.environ.get("XLA_FLAGS")
    lines = [
        "", f"## Physics determinism: {device_name()}, {datetime.date.today().isoformat()}", "",
        f"jax {jax.__version__}" + (f", XLA_FLAGS `{flags}`" if flags else "")
        + f". Command: `{shlex.join(['python', *sys.argv])}`", "",
        "| env | physics | batch | steps | state elements | differing | max abs difference "
        "| checksums equal |",
        "|---|---|---|---|---|---|---|---|",
    ]
    append(args.results, "\n".join(lines) + "\n")
    for env_id in args.envs:
        for physics in args.physics:
            r = compare(env_id, physics, args.batch, args.steps)
            row = (f"| {r['env']} | {r['physics']} | {r['batch']} | {r['steps']} | "
                   f"{r['elements']:,} | {r['differing']:,} | {r['max_diff']:.3g} | "
                   f"{r['checksums_equal']} |")
            print(row, flush=True)
            append(args.results, row + "\n")


if __name__ == "__main__":
    main()
