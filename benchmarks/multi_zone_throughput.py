"""Env-steps per second of the multi-agent Zone worlds (one env step = every agent of a world).

One measurement = a jitted `lax.scan` of `--steps` steps of `BatchedEnv(MultiAutoReset(env), B)`
(or the raw env with `--resets off`) with uniformly random actions for every agent; each step's
observation, labels, reward and flags are folded into a checksum carried by the scan, so XLA
cannot drop any of the work. "exact" = the auto-reset computes a full reset (a fresh layout by
the original's multi-agent rejection sampler, every robot's forward pass) for every world at
every step and selects it where the world's episode ended; "bank" = the same with opt-in
`env.with_map_bank(key, params, --bank-size)` resets (exact layouts sampled up front). Compile
time is measured apart; the run is timed after one warm-up call, with `block_until_ready`, best
and median of --repeats.
A Markdown table is appended to --results with device, versions, date and command.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import jaxlib

import specrl_jax
from specrl_jax.envs.multi import MultiAutoReset
from specrl_jax.envs.wrappers import BatchedEnv

sys.path.insert(0, str(Path(__file__).parent))
from env_throughput import checksum, make_rollout  # noqa: E402


def checksum_with_symbol(obs: Any, reward: jax.Array, done: jax.Array,
                         info: dict[str, Any]) -> jax.Array:
    """env_throughput's checksum plus the joint symbol, which the multi-agent worlds report."""
    return checksum(obs, reward, done, info) + jnp.sum(info["symbol"]).astype(jnp.float32)


def measure(env_id: str, mode: str, num_envs: int, args: argparse.Namespace) -> dict[str, Any]:
    overrides = {"collisions": True} if args.collisions else {}
    env, params = specrl_jax.make(env_id, **overrides)
    key_bank, key_reset, key_run = jax.random.split(jax.random.key(args.seed), 3)
    if mode == "bank":
        params = jax.block_until_ready(env.with_map_bank(key_bank, params, args.bank_size))
    batched = BatchedEnv(env if mode == "off" else MultiAutoReset(env), num_envs)
    start = time.perf_counter()
    _, state = jax.block_until_ready(jax.jit(batched.reset)(key_reset, params))
    reset_s = time.perf_counter() - start
    rollout = make_rollout(batched, params, args.steps, checksum_with_symbol)
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
    return {
        "env": env_id + (" (collisions on)" if args.collisions else ""),
        "agents": env.num_agents, "reset": mode, "batch": num_envs, "steps": args.steps,
        "best": steps / min(times), "median": steps / statistics.median(times),
        "compile_s": compile_s, "first_reset_s": reset_s, "checksum": float(total),
    }


def header(args: argparse.Namespace) -> str:
    device = jax.devices()[0]
    versions = (
        f"jax {jax.__version__}, jaxlib {jaxlib.__version__}, specrl_jax {specrl_jax.__version__}, "
        f"Python {platform.python_version()}"
    )
    return "\n".join([
        "",
        f"### Multi-agent Zone throughput: {device.platform}: {device.device_kind}, "
        f"{datetime.date.today().isoformat()}",
        "",
        f"Versions: {versions}. Command: `{shlex.join(['python', *sys.argv])}`",
        "",
        "| env | agents | reset | batch | steps/call | env-steps/s (best) | env-steps/s (median) | "
        "agent-steps/s (best) | compile s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]) + "\n"


def row(r: dict[str, Any]) -> str:
    return (
        f"| {r['env']} | {r['agents']} | {r['reset']} | {r['batch']:,} | {r['steps']} | "
        f"{r['best']:,.0f} | {r['median']:,.0f} | {r['best'] * r['agents']:,.0f} | "
        f"{r['compile_s']:.1f} |\n"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["PointLTL0MA3-v0", "PointLTL0MA2-v0"])
    parser.add_argument("--batches", nargs="+", type=int, default=[16384, 65536])
    parser.add_argument("--resets", nargs="+", choices=["exact", "bank", "off"],
                        default=["exact", "off"])
    parser.add_argument("--bank-size", type=int, default=65536)
    parser.add_argument("--steps", type=int, default=50, help="env steps per compiled call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--collisions", action="store_true", help="turn the collision switch on")
    parser.add_argument("--results", default="docs/results.md")
    args = parser.parse_args()
    written = False
    for env_id in args.envs:
        for mode in args.resets:
            for num_envs in args.batches:
                try:
                    r = measure(env_id, mode, num_envs, args)
                except jax.errors.JaxRuntimeError as err:
                    if "RESOURCE_EXHAUSTED" not in str(err):
                        raise
                    print(f"{env_id} reset={mode} batch={num_envs}: out of memory", flush=True)
                    continue
                print(
                    f"{env_id} reset={mode} batch={num_envs}: {r['best']:,.0f} env-steps/s "
                    f"(median {r['median']:,.0f}), compile {r['compile_s']:.1f}s, first reset "
                    f"{r['first_reset_s']:.1f}s", flush=True,
                )
                with open(args.results, "a") as f:
                    f.write(("" if written else header(args)) + row(r))
                written = True


if __name__ == "__main__":
    main()
