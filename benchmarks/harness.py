"""The benchmarks' one timed rollout and one result row.

`time_rollout(env, params, steps)` times a jitted `lax.scan` of `steps` uniformly random actions
on a batched env (`specrl_jax.envs.batch(env, B)`, or `BatchedEnv(TaskEnv(...), B)` for the task
loop: anything with `reset`, `step`, `sample_actions` and `num_envs`). Every step's observation,
labels, reward and done flags are folded into a float32 checksum carried by the scan, so XLA
cannot drop any of the work. Compilation is timed apart (`lower(...).compile()`); the run is timed
after one warm-up call with `block_until_ready`, best and median of `repeats`.

`row(figure, value, batch)` makes a result row with the keys of the project's measurements
(figure, value, device, batch, versions, date, command); `emit(row, out)` prints it as one JSON
line and appends it to `out` (a JSON-lines file) when given.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

Fold = Callable[[Any, jax.Array, jax.Array, dict], jax.Array]


def checksum(obs: Any, reward: jax.Array, done: jax.Array, info: dict[str, Any]) -> jax.Array:
    """A float32 scalar that depends on every output of a step."""
    total = jnp.sum(reward, dtype=jnp.float32) + jnp.sum(done, dtype=jnp.float32)
    total = total + jnp.sum(info["propositions"], dtype=jnp.float32)
    for leaf in jax.tree.leaves(obs):
        total = total + jnp.sum(leaf, dtype=jnp.float32)
    return total


def make_rollout(env: Any, params: Any, steps: int, fold: Fold = checksum) -> Callable:
    """`rollout(key, state) -> (state, checksum)`: `steps` random-action steps of the batched
    `env` in one jitted scan (the state argument is donated)."""

    def body(carry: tuple, _: None) -> tuple:
        key, state, total = carry
        key, key_action, key_step = jax.random.split(key, 3)
        actions = env.sample_actions(key_action)
        obs, state, reward, terminated, truncated, info = env.step(key_step, state, actions, params)
        return (key, state, total + fold(obs, reward, terminated | truncated, info)), None

    def rollout(key: jax.Array, state: Any) -> tuple[Any, jax.Array]:
        (_, state, total), _ = jax.lax.scan(body, (key, state, jnp.float32(0)), None, steps)
        return state, total

    return jax.jit(rollout, donate_argnums=1)


def time_rollout(env: Any, params: Any, steps: int, repeats: int = 3, seed: int = 0,
                 fold: Fold = checksum) -> dict[str, Any]:
    """Time `steps` random-action steps of the batched `env` from a fresh reset.

    Returns `steps_per_s` (best of `repeats`), `median_steps_per_s`, `compile_s`, `checksum` (of
    the last timed call) and, for further runs, `rollout` (compiled), `state` and `key`.
    """
    key_reset, key_run = jax.random.split(jax.random.key(seed))
    _, state = jax.jit(env.reset)(key_reset, params)
    start = time.perf_counter()
    rollout = make_rollout(env, params, steps, fold).lower(key_run, state).compile()
    compile_s = time.perf_counter() - start
    state, total = jax.block_until_ready(rollout(key_run, state))  # warm-up
    times = []
    for repeat in range(repeats):
        start = time.perf_counter()
        state, total = jax.block_until_ready(rollout(jax.random.fold_in(key_run, repeat), state))
        times.append(time.perf_counter() - start)
    env_steps = env.num_envs * steps
    return {
        "steps_per_s": env_steps / min(times),
        "median_steps_per_s": env_steps / statistics.median(times),
        "compile_s": compile_s,
        "checksum": float(total),
        "rollout": rollout,
        "state": state,
        "key": key_run,
    }


def repeat_difference(rollout: Callable, key: jax.Array, state: Any) -> dict[str, Any]:
    """Run `rollout(key, state)` twice from copies of `state`: how many elements of the final
    states differ, the largest absolute difference, and whether the checksums agree."""
    first, total_a = rollout(key, jax.tree.map(jnp.copy, state))
    second, total_b = rollout(key, jax.tree.map(jnp.copy, state))
    differ, largest, elements = 0, 0.0, 0
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(second)):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        a64, b64 = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
        differ += int(jnp.sum(a != b))
        largest = max(largest, float(jnp.max(jnp.abs(a64 - b64), initial=0.0)))
        elements += a.size
    return {"elements": elements, "differing": differ, "max_abs_difference": largest,
            "same_checksum": float(total_a) == float(total_b)}


def device_name(using: int = 1) -> str:
    """The device kind, with how many of this machine's devices a figure used."""
    device = jax.devices()[0]
    name = device.device_kind if device.platform != "cpu" else f"{os.cpu_count()}-core CPU"
    return name + (f" ({jax.device_count()} devices, using {using})" if jax.device_count() > 1
                   else "")


def versions() -> dict[str, str]:
    """Installed versions of the packages a figure depends on (absent ones left out)."""
    found = {}
    for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "warp-lang", "specrl_jax"):
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return found


def row(figure: str, value: Any, batch: int | None = None, **extra: Any) -> dict[str, Any]:
    """One result row: the figure, its value, and where, when and how it was measured (on
    `extra["devices"]` devices, else one)."""
    return {
        "figure": figure,
        "value": value,
        "device": device_name(extra.get("devices", 1)),
        "batch": batch,
        "versions": versions(),
        "date": datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
        "command": shlex.join(["python", *sys.argv]),
        **extra,
    }


def emit(result: dict[str, Any], out: str | None = None) -> None:
    """Print `result` as one JSON line; append it to the JSON-lines file `out` when given (at
    once, so rows measured before a crash or a timeout are kept)."""
    line = json.dumps(result, default=str)
    print(line, flush=True)
    if out:
        directory = os.path.dirname(out)
        if directory:
            os.makedirs(directory, exist_ok=True)
        with open(out, "a") as f:
            f.write(line + "\n")
