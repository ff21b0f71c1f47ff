"""Env-steps per second of any registered world (`--envs`), auto-resetting, over batch sizes.

Every measurement is `harness.time_rollout`: one jitted scan of `--steps` uniformly random actions
on `--batches` worlds, every output folded into a checksum; compile time apart; best and median of
`--repeats`. One env step of a multi-agent world moves every agent; a Vision world renders its
camera frame every step.

Loops (`--loops`):
  world  `batch(env, B)`: the world with its auto-reset;
  task   `BatchedEnv(TaskEnv(env, specs), B)`: the task loop over the world's first finite paper
         suite (world + automaton + auto-reset with a fresh layout and spec); with `world` beside
         it, the task layer's cost.
Resets (`--resets`):
  exact  every reset samples a fresh layout (the env's own sampler);
  bank   params from `env.with_map_bank(key, params, --bank-size)` (opt-in, where the env has it);
  off    no auto-reset (the raw world step; world loop only).

`--physics {auto,jax,warp}` and `--solver KEY=VALUE ...` set a Zone world's physics backend and
solver fields; `--env-option KEY=VALUE` any world's option (e.g. the arm's `motor_solve=pallas`). `--determinism` also runs each measured rollout twice from one state and key and
reports how many state elements differ (MuJoCo Warp's atomic adds on a GPU may differ in the last
bits). Each figure is printed as one JSON row (`harness.row`) and appended to `--out` if given.

    python benchmarks/env_throughput.py --envs LetterLTL0-v0 PointLTL0-v0 --batches 65536 262144
    python benchmarks/env_throughput.py --envs LetterLTL0-v0 --loops world task --resets bank
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from typing import Any

import jax

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import harness

import specrl_jax
from specrl_jax import automata, families, specs
from specrl_jax.envs import BatchedEnv, batch
from specrl_jax.tasks import TaskEnv

LOOPS = ("world", "task")
RESETS = ("exact", "bank", "off")


def make_env(env_id: str, args: argparse.Namespace) -> tuple[Any, Any]:
    overrides = {"physics": args.physics} if args.physics else {}
    overrides.update(args.env_option)
    env, params = specrl_jax.make(env_id, **overrides)
    if args.solver:
        solver = dataclasses.replace(env.config.solver, **args.solver)
        env, params = specrl_jax.make(env_id, solver=solver, **overrides)
    return env, params


def paper_specs(env: Any) -> tuple[str, Any]:
    """The world's first finite paper suite whose formulas are over its propositions, stacked."""
    for name in families.of(env).suites:
        if "/finite/" not in name:
            continue
        try:
            return name, automata.compile_suite(specs.suite(name), env.propositions, env.alphabet)
        except ValueError:  # formulas over other propositions (another variant of the family)
            continue
    raise ValueError(f"no finite paper suite of family {env.family!r} fits {env!r}")


def label(env_id: str, env: Any, loop: str, reset: str, args: argparse.Namespace) -> str:
    settings = []
    backend = getattr(getattr(env, "physics", None), "backend", None)  # Zone worlds
    if backend:
        settings.append(f"physics {backend}")
    settings += [f"{k}={v}" for k, v in (*args.solver.items(), *args.env_option.items())]
    what = {"exact": "exact auto-reset", "bank": f"bank auto-reset ({args.bank_size:,} layouts)",
            "off": "raw step (no reset)"}[reset]
    return ", ".join([env_id, f"{loop} loop", what, *settings])


def measure(env_id: str, loop: str, reset: str, num_envs: int, args: argparse.Namespace) -> None:
    env, params = make_env(env_id, args)
    if loop == "task" and (reset == "off" or getattr(env, "num_agents", 1) > 1):
        why = ("the task loop always resets" if reset == "off" else
               "several agents (multi-agent tasks run through the coordinator)")
        print(f"{env_id}: no task loop with reset {reset!r}: {why}; skipped", file=sys.stderr,
              flush=True)
        return
    extra: dict[str, Any] = {}
    if reset == "bank":
        if not hasattr(env, "with_map_bank"):
            print(f"{env_id}: no layout bank, 'bank' skipped", file=sys.stderr, flush=True)
            return
        start = time.perf_counter()
        params = jax.block_until_ready(
            env.with_map_bank(jax.random.key(args.seed + 1), params, args.bank_size))
        extra["bank_build_s"] = round(time.perf_counter() - start, 2)
    if loop == "task":
        suite, compiled = paper_specs(env)
        extra["suite"] = suite
        world = BatchedEnv(TaskEnv(env, compiled), num_envs)
    else:
        world = batch(env, num_envs, auto_reset=reset != "off")
    try:
        timing = harness.time_rollout(world, params, args.steps, args.repeats, args.seed)
    except jax.errors.JaxRuntimeError as err:
        if "RESOURCE_EXHAUSTED" not in str(err):
            raise
        print(f"{env_id} {loop} {reset} batch {num_envs}: out of memory", file=sys.stderr)
        return
    figure = label(env_id, env, loop, reset, args)
    rate = f"{timing['steps_per_s']:,.0f} env-steps/s (median {timing['median_steps_per_s']:,.0f})"
    harness.emit(harness.row(
        figure, rate, num_envs, steps_per_call=args.steps, compile_s=round(timing["compile_s"], 2),
        steps_per_s=timing["steps_per_s"], checksum=timing["checksum"], **extra), args.out)
    if args.determinism:
        diff = harness.repeat_difference(timing["rollout"], timing["key"], timing["state"])
        value = (f"{diff['differing']:,} of {diff['elements']:,} state elements differ "
                 f"(max {diff['max_abs_difference']:.3g})")
        harness.emit(harness.row(f"Repeatability, {figure}, {args.steps} steps", value, num_envs,
                                 **diff), args.out)


def _override(pair: str, parser: argparse.ArgumentParser, flag: str) -> tuple[str, Any]:
    key, sep, value = pair.partition("=")
    if not sep or not key:
        parser.error(f"{flag} takes KEY=VALUE pairs, got {pair!r}")
    if value in ("True", "False"):
        return key, value == "True"
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, value


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["LetterLTL0-v0", "PointLTL0-v0"],
                        help="env IDs (`specrl-jax list` or specrl_jax.list_envs())")
    parser.add_argument("--batches", nargs="+", type=int, default=[1024])
    parser.add_argument("--loops", nargs="+", choices=LOOPS, default=["world"])
    parser.add_argument("--resets", nargs="+", choices=RESETS, default=["exact"])
    parser.add_argument("--steps", type=int, default=100, help="env steps per compiled call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--bank-size", type=int, default=65536)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--prng", default="threefry2x32",
                        choices=["threefry2x32", "rbg", "unsafe_rbg"])
    parser.add_argument("--env-option", action="append", default=[],
                        metavar="KEY=VALUE", help="an option of the world, e.g. motor_solve=pallas")
    parser.add_argument("--physics", choices=["auto", "jax", "warp"], default=None,
                        help="Zone worlds' physics backend (default: the env's own, auto)")
    parser.add_argument("--solver", nargs="*", default=[], metavar="KEY=VALUE",
                        help="Zone worlds: overrides of the env's physics `Solver` fields")
    parser.add_argument("--determinism", action="store_true",
                        help="also report whether each rollout repeats bit for bit")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args(argv)
    args.solver = dict(_override(pair, parser, "--solver") for pair in args.solver)
    args.env_option = dict(_override(pair, parser, "--env-option") for pair in args.env_option)
    known = specrl_jax.list_envs()
    unknown = [e for e in args.envs if e not in known]
    if unknown:
        parser.error(f"unknown env IDs {unknown}; known: {', '.join(known)}")
    if min(args.batches) < 1 or min(args.steps, args.repeats, args.bank_size) < 1:
        parser.error("--batches, --steps, --repeats and --bank-size must be positive")
    return args


def main() -> None:
    args = parse_args()
    jax.config.update("jax_default_prng_impl", args.prng)
    for env_id in args.envs:
        for loop in args.loops:
            for reset in args.resets:
                for num_envs in args.batches:
                    measure(env_id, loop, reset, num_envs, args)


if __name__ == "__main__":
    main()
