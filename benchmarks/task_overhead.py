"""What the task layer adds to an auto-resetting world step.

For each env: the world with its per-world auto-reset (`BatchedEnv(AutoReset(env), B)`, the reset
the task loop runs) against `TaskEnv.step` under `vmap` (world + automaton of the world's paper
specs + auto-reset with a fresh spec), both in one `lax.scan` of random actions whose outputs
are folded into a checksum; beside them `batch(env, B)`'s default reset (a few fresh resets per
step scattered into the finished worlds). Resets: LetterWorld from a map bank (as training runs),
ZoneEnv exact. Interleaved repeats; best and median per variant.

    python benchmarks/task_overhead.py --envs LetterLTL0-v0 PointLTL0-v0 --batch 65536
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax import automata, specs
from specrl_jax.envs import batch
from specrl_jax.envs.wrappers import AutoReset, BatchedEnv
from specrl_jax.tasks import TaskEnv

SUITES = {"Letter": "letter/finite/ind", "Point": "zone/finite/ind"}


def checksum(obs, reward, terminated, truncated) -> jax.Array:
    leaves = [jnp.sum(x.astype(jnp.float32)) for x in jax.tree.leaves(obs)]
    return sum(leaves) + jnp.sum(reward) + jnp.sum(terminated) + jnp.sum(truncated)


def variants(env_id: str, num_envs: int, steps: int):
    env, params = specrl_jax.make(env_id)
    if env_id.startswith("Letter"):
        params = jax.block_until_ready(env.with_map_bank(jax.random.key(9), params, 65536))
    suite = SUITES[env_id[:6] if env_id.startswith("Letter") else env_id[:5]]
    compiled = automata.stack([automata.compile_spec(f, env.propositions, alphabet=env.alphabet)
                               for f in specs.suite(suite)])
    world = BatchedEnv(AutoReset(env), num_envs)
    batched = batch(env, num_envs)  # the default: a few exact resets scattered per step
    task = TaskEnv(env, compiled)
    task_step = jax.vmap(task.step, in_axes=(0, 0, 0, None))

    def run(step_fn, state, key):
        def body(carry, key_step):
            state, total = carry
            key_action, key_env = jax.random.split(key_step)
            action = world.sample_actions(key_action)
            obs, state, reward, terminated, truncated, _ = step_fn(key_env, state, action)
            return (state, total + checksum(obs, reward, terminated, truncated)), None

        (state, total), _ = jax.lax.scan(body, (state, 0.0), jax.random.split(key, steps))
        return state, total

    world_run = jax.jit(lambda s, k: run(lambda kk, st, a: world.step(kk, st, a, params), s, k),
                        donate_argnums=0)
    task_run = jax.jit(lambda s, k: run(
        lambda kk, st, a: task_step(jax.random.split(kk, num_envs), st, a, params), s, k),
        donate_argnums=0)
    batched_run = jax.jit(lambda s, k: run(lambda kk, st, a: batched.step(kk, st, a, params), s, k),
                          donate_argnums=0)
    world_state = world.reset(jax.random.key(0), params)[1]
    task_state = jax.vmap(task.reset, in_axes=(0, None))(
        jax.random.split(jax.random.key(0), num_envs), params)[1]
    return {"world": (world_run, world_state), "task": (task_run, task_state),
            "batch": (batched_run, world.reset(jax.random.key(0), params)[1])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["LetterLTL0-v0", "PointLTL0-v0"])
    parser.add_argument("--batch", type=int, default=65536)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    print(f"device {jax.devices()[0].device_kind}, jax {jax.__version__}, batch {args.batch}, "
          f"{args.steps} steps per call, {args.repeats} interleaved repeats")
    print("| env | world + auto-reset (best / median env-steps/s) | task layer (best / median) "
          "| overhead (best, median) | `batch(env, B)` default (best / median) |")
    print("|---|---|---|---|---|")
    for env_id in args.envs:
        runs = variants(env_id, args.batch, args.steps)
        times = {name: [] for name in runs}
        states = {name: state for name, (_, state) in runs.items()}
        for name, (fn, _) in runs.items():  # compile
            states[name], total = fn(states[name], jax.random.key(1))
            total.block_until_ready()
        for r in range(args.repeats):
            for name, (fn, _) in runs.items():
                start = time.perf_counter()
                states[name], total = fn(states[name], jax.random.key(2 + r))
                total.block_until_ready()
                times[name].append(time.perf_counter() - start)
        rate = {n: args.batch * args.steps / np.array(t) for n, t in times.items()}
        best = {n: r.max() for n, r in rate.items()}
        median = {n: float(np.median(r)) for n, r in rate.items()}
        print(f"| {env_id} | {best['world']:,.0f} / {median['world']:,.0f} | "
              f"{best['task']:,.0f} / {median['task']:,.0f} | "
              f"{100 * (best['world'] / best['task'] - 1):+.1f}%, "
              f"{100 * (median['world'] / median['task'] - 1):+.1f}% | "
              f"{best['batch']:,.0f} / {median['batch']:,.0f} |", flush=True)


if __name__ == "__main__":
    main()
