"""Env-steps per second of every registered env (or --envs), auto-resetting, over batch sizes.

One measurement = a jitted `lax.scan` of `--steps` steps of `batch(env, B)` (AutoReset +
BatchedEnv) with uniformly random actions; every step's observation, labels, reward and done
flags are folded into a checksum carried by the scan, so XLA cannot drop any of the work.
Compile time is measured apart; the run is timed after one warm-up call, with
`block_until_ready`, best and median of --repeats. Reset modes:

  exact  every reset samples a fresh layout with the env's default sampler (the default `reset`);
  bank   params from `env.with_map_bank(key, params, --bank-size)` when the env offers it;
  off    no auto-reset (the raw step, for reference: what resets cost).

`--physics {auto,jax,warp}` sets Zone envs' physics (default: the env's, "auto": MuJoCo Warp for
Car and Ant on one CUDA GPU with warp-lang, MJX's JAX implementation otherwise); the env column
names the backend that ran, e.g. `CarLTL0-v0 (warp)`. `--solver KEY=VALUE ...`
overrides fields of a Zone env's physics settings (`zone.Solver`), named in the env column too.

Results are appended to docs/results.md (or --results) with device, versions, date, command.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import platform
import shlex
import statistics
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import jaxlib

import specrl_jax
from specrl_jax.envs.wrappers import BatchedEnv, batch

RESET_MODES = ("exact", "bank", "off")


def checksum(obs: Any, reward: jax.Array, done: jax.Array, info: dict[str, Any]) -> jax.Array:
    """A float32 scalar that depends on every output of the step."""
    total = jnp.sum(reward) + jnp.sum(done) + jnp.sum(info["propositions"])
    for leaf in jax.tree.leaves(obs):
        total = total + jnp.sum(leaf, dtype=jnp.float32)
    return total.astype(jnp.float32)


def make_rollout(env: BatchedEnv, params: Any, num_steps: int, fold=checksum):
    """`rollout(key, state) -> (state, checksum)`: `num_steps` random-action steps in a scan;
    `fold(obs, reward, done, info)` reduces each step's outputs to a float32 scalar."""

    def body(carry: tuple, _: None) -> tuple:
        key, state, total = carry
        key, key_action, key_step = jax.random.split(key, 3)
        actions = env.sample_actions(key_action)
        obs, state, reward, terminated, truncated, info = env.step(key_step, state, actions, params)
        return (key, state, total + fold(obs, reward, terminated | truncated, info)), None

    def rollout(key: jax.Array, state: Any) -> tuple[Any, jax.Array]:
        (_, state, total), _ = jax.lax.scan(body, (key, state, jnp.float32(0)), None, num_steps)
        return state, total

    return jax.jit(rollout, donate_argnums=1)


def measure(
    env_id: str, mode: str, num_envs: int, args: argparse.Namespace
) -> dict[str, Any] | None:
    env, params = specrl_jax.make(env_id, **({"physics": args.physics} if args.physics else {}))
    if args.solver:
        if not hasattr(getattr(env, "config", None), "solver"):
            return None
        solver = dataclasses.replace(env.config.solver, **args.solver)
        env, params = specrl_jax.make(
            env_id, solver=solver, **({"physics": args.physics} if args.physics else {})
        )
    key_bank, key_reset, key_run = jax.random.split(jax.random.key(args.seed), 3)
    if mode == "bank":
        if not hasattr(env, "with_map_bank"):
            return None
        start = time.perf_counter()
        params = jax.block_until_ready(env.with_map_bank(key_bank, params, args.bank_size))
        bank_s = time.perf_counter() - start
    else:
        bank_s = None
    batched = batch(env, num_envs, auto_reset=mode != "off")
    _, state = jax.jit(batched.reset)(key_reset, params)
    rollout = make_rollout(batched, params, args.steps)
    start = time.perf_counter()
    compiled = rollout.lower(key_run, state).compile()
    compile_s = time.perf_counter() - start
    state, total = jax.block_until_ready(compiled(key_run, state))  # warm-up
    times = []
    for repeat in range(args.repeats):
        start = time.perf_counter()
        state, total = jax.block_until_ready(compiled(jax.random.fold_in(key_run, repeat), state))
        times.append(time.perf_counter() - start)
    steps = num_envs * args.steps
    backend = getattr(getattr(env, "physics", None), "backend", None)  # Zone envs only
    settings = [backend] if backend else []
    settings += [f"{k}={v}" for k, v in args.solver.items()]
    return {
        "env": env_id + (f" ({', '.join(settings)})" if settings else ""),
        "reset": mode,
        "batch": num_envs,
        "steps": args.steps,
        "best": steps / min(times),
        "median": steps / statistics.median(times),
        "compile_s": compile_s,
        "bank_s": bank_s,
        "checksum": float(total),
    }


def device_name() -> str:
    device = jax.devices()[0]
    return f"{device.platform}: {device.device_kind}" + (
        f" ({jax.device_count()} devices, using 1)" if jax.device_count() > 1 else ""
    )


def results_header(args: argparse.Namespace) -> str:
    versions = (
        f"jax {jax.__version__}, jaxlib {jaxlib.__version__}, specrl_jax {specrl_jax.__version__}, "
        f"Python {platform.python_version()}, PRNG {jax.config.jax_default_prng_impl}"
    )
    lines = [
        "",
        f"## Env throughput: {device_name()}, {datetime.date.today().isoformat()}",
        "",
        f"Versions: {versions}. Host: {platform.machine()}, {os.cpu_count()} CPU cores."
        + (f" XLA_FLAGS: `{os.environ['XLA_FLAGS']}`." if os.environ.get("XLA_FLAGS") else ""),
        f"Command: `{shlex.join(['python', *sys.argv])}`",
        "",
        "| env | reset | batch | steps/call | env-steps/s (best) | env-steps/s (median) | compile s | bank build s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    return "\n".join(lines) + "\n"


def results_row(r: dict[str, Any], args: argparse.Namespace) -> str:
    bank = "" if r["bank_s"] is None else f"{r['bank_s']:.1f} ({args.bank_size} maps)"
    return (
        f"| {r['env']} | {r['reset']} | {r['batch']} | {r['steps']} | {r['best']:,.0f} | "
        f"{r['median']:,.0f} | {r['compile_s']:.1f} | {bank} |\n"
    )


def append(path: str, text: str) -> None:
    """Append at once, so rows measured before a crash or timeout are kept."""
    with open(path, "a") as f:
        f.write(text)


def _override(pair: str, parser: argparse.ArgumentParser) -> tuple[str, Any]:
    key, sep, value = pair.partition("=")
    if not sep or not key:
        parser.error(f"--solver takes KEY=VALUE pairs, got {pair!r}")
    if value in ("True", "False"):
        return key, value == "True"
    try:
        return key, int(value)
    except ValueError:
        return key, value


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=None, help="env IDs (default: all registered)")
    parser.add_argument("--batches", nargs="+", type=int, default=[64, 1024])
    parser.add_argument("--resets", nargs="+", choices=RESET_MODES, default=["exact", "bank"])
    parser.add_argument("--steps", type=int, default=100, help="env steps per compiled call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bank-size", type=int, default=65536)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--prng",
        default="threefry2x32",
        choices=["threefry2x32", "rbg", "unsafe_rbg"],
        help="JAX PRNG implementation (threefry2x32 is JAX's default)",
    )
    parser.add_argument(
        "--physics", choices=["auto", "jax", "warp"], default=None,
        help="physics backend of Zone envs (default: the env's, auto)",
    )
    parser.add_argument(
        "--solver", nargs="*", default=[], metavar="KEY=VALUE",
        help="Zone envs: overrides of the env's `Solver` fields (ints, True/False or names), "
        "e.g. max_contacts=0 substep_sensors=True for the settings before issue 18",
    )
    parser.add_argument("--results", default="docs/results.md")
    args = parser.parse_args()
    args.solver = dict(_override(pair, parser) for pair in args.solver)
    known = specrl_jax.list_envs()
    args.envs = args.envs or known
    unknown = [e for e in args.envs if e not in known]
    if unknown:
        parser.error(f"unknown env IDs {unknown}; known: {', '.join(known)}")
    if min(args.batches) < 1 or args.steps < 1 or args.repeats < 1 or args.bank_size < 1:
        parser.error("--batches, --steps, --repeats and --bank-size must be positive")
    return args


def main() -> None:
    args = parse_args()
    jax.config.update("jax_default_prng_impl", args.prng)
    header_written = False
    for env_id in args.envs:
        for mode in args.resets:
            for num_envs in args.batches:
                try:
                    row = measure(env_id, mode, num_envs, args)
                except jax.errors.JaxRuntimeError as err:
                    if "RESOURCE_EXHAUSTED" not in str(err):
                        raise
                    print(f"{env_id} reset={mode} batch={num_envs}: out of memory", flush=True)
                    continue
                if row is None:
                    print(f"{env_id}: no {mode!r} reset mode, skipped", flush=True)
                    continue
                print(
                    f"{env_id} reset={mode} batch={num_envs}: {row['best']:,.0f} env-steps/s "
                    f"(median {row['median']:,.0f}), compile {row['compile_s']:.1f}s",
                    flush=True,
                )
                if not header_written:
                    append(args.results, results_header(args))
                    header_written = True
                append(args.results, results_row(row, args))


if __name__ == "__main__":
    main()
