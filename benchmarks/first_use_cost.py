"""What a new user waits for, and what invalid-action handling costs a step.

    python benchmarks/first_use_cost.py startup --env PointLTL0-v0   # one fresh process
    python benchmarks/first_use_cost.py startups --env PointLTL0-v0  # cold, then warm cache
    python benchmarks/first_use_cost.py step --env LetterLTL0-v0 --batch 4096

`startup` times, in this process: the import, `make`, the first eager reset + step, later eager
steps, a first and a second `gymnasium.make` of the ID (each with a reset and a step). `startups`
runs `startup` in two fresh processes sharing a new empty `SPECRL_JAX_CACHE_DIR` (cold, then
warm). `step` times the jitted batched step (no auto-reset) of `Env.step` against the same world
stepped without the invalid-action handling (`step_env` plus truncation, as before it).
Prints one JSON line per measurement.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time


def _now() -> float:
    return time.perf_counter()


def startup(env_id: str) -> dict:
    start = _now()
    import jax
    import numpy as np

    import specrl_jax
    import specrl_jax.gym  # noqa: F401

    out = {"import_s": _now() - start, "cache": jax.config.jax_compilation_cache_dir}
    import gymnasium

    start = _now()
    env, params = specrl_jax.make(env_id)
    out["make_s"] = _now() - start
    action = env.action_space.sample(jax.random.key(3))
    start = _now()
    _, state = env.reset(jax.random.key(0), params)
    jax.block_until_ready(env.step(jax.random.key(1), state, action, params))
    out["first_reset_step_s"] = _now() - start
    start = _now()
    for i in range(5):
        jax.block_until_ready(env.step(jax.random.key(2 + i), state, action, params))
    out["eager_step_s"] = (_now() - start) / 5
    for name in ("first_gym_make_s", "second_gym_make_s"):
        start = _now()
        gym_env = gymnasium.make(env_id)
        gym_env.reset(seed=0)
        gym_env.step(np.asarray(action))
        out[name] = _now() - start
    return out


def startups(env_id: str) -> list[dict]:
    results = []
    with tempfile.TemporaryDirectory() as cache_dir:
        for run in ("cold", "warm"):
            env = {**os.environ, "SPECRL_JAX_CACHE_DIR": cache_dir}
            proc = subprocess.run(
                [sys.executable, __file__, "startup", "--env", env_id], env=env,
                capture_output=True, text=True, check=True,
            )
            results.append({"run": run, **json.loads(proc.stdout.strip().splitlines()[-1])})
    return results


def step_cost(env_id: str, batch: int, repeats: int) -> dict:
    import jax

    import specrl_jax

    env, params = specrl_jax.make(env_id)
    keys = jax.random.split(jax.random.key(0), batch)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    actions = jax.vmap(env.action_space.sample)(jax.random.split(jax.random.key(1), batch))

    def without_checks(key, state, action, params):
        obs, state, reward, terminated, info = env.step_env(key, state, action, params)
        return obs, state, reward, terminated, (state.time >= params.max_steps) & ~terminated, info

    compiled = {}

    def timed(step_fn) -> float:
        if step_fn not in compiled:
            compiled[step_fn] = jax.jit(jax.vmap(step_fn, in_axes=(0, 0, 0, None)))
        fn = compiled[step_fn]
        jax.block_until_ready(fn(keys, state, actions, params))
        best = float("inf")
        for _ in range(repeats):
            start = _now()
            jax.block_until_ready(fn(keys, state, actions, params))
            best = min(best, _now() - start)
        return best

    # interleaved, best of `repeats` each, five times, so drift on a shared machine hits both
    step_new = env.step  # one bound method object, compiled once
    old, new = float("inf"), float("inf")
    for _ in range(5):
        old, new = min(old, timed(without_checks)), min(new, timed(step_new))
    return {
        "env": env_id, "batch": batch, "device": str(jax.devices()[0]), "jax": jax.__version__,
        "without_checks_ms": old * 1e3, "env_step_ms": new * 1e3,
        "overhead_pct": 100 * (new - old) / old,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("startup", "startups", "step"))
    parser.add_argument("--env", default="LetterLTL0-v0")
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    if args.mode == "startup":
        print(json.dumps(startup(args.env)))
    elif args.mode == "startups":
        for row in startups(args.env):
            print(json.dumps({"env": args.env, **row}))
    else:
        print(json.dumps(step_cost(args.env, args.batch, args.repeats)))


if __name__ == "__main__":
    main()
