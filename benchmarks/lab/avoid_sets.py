"""Infinite specs with smaller avoid sets, and their subgoals alone: do a policy's violations
come from the size of the avoid set, from staying, or from many subgoals in a row?

For each spec `goal & G !(a | b | c)` of an infinite suite this script evaluates, with a policy
(a results-store cell, its seed 1, or `random`) over `--episodes` episodes of `--horizon` steps:
the spec; its variants that avoid fewer propositions (`--keep`: none given, every variant with
one fewer; else for each count K the first K and the last K, 0 dropping `G !(...)`); and with
`--subgoals`, for each proposition `r` of the goal the one-subgoal task `!(a | b | c) U r` at the
world's own time limit: the violation rate of one subgoal under the spec's avoid set, which
compounds over the many subgoals of a long episode. It prints one JSON row per suite
(`benchmarks/harness.py`; appended to `--out` if given): each spec's violation rate and mean
accepting visits (success rate for the subgoals). With the method's own test-time agent (sampled
actions on infinite specs, as in the suites).

    python benchmarks/lab/avoid_sets.py --policy PointLTL0-v0/deepltl --episodes 100
    python benchmarks/lab/avoid_sets.py --policy LetterLTL0-v0/deepltl --env LetterLTL0-v0 \\
        --suites letter/infinite/rec letter/infinite/rsp --horizon 750 --keep 0 1 3 --subgoals
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness


def split(formula: str) -> tuple[str, list[str]]:
    """`goal & G !(a | b | ...)` -> (goal, [a, b, ...])."""
    if formula.count(" & G !") != 1:
        raise ValueError(f"{formula!r} is not of the form 'goal & G !(a | b | ...)'")
    goal, avoid = formula.split(" & G !")
    return goal, avoid.strip("()").split(" | ")


def disjunction(props: tuple[str, ...] | list[str]) -> str:
    """`a` or `(a | b | ...)`."""
    return props[0] if len(props) == 1 else "(" + " | ".join(props) + ")"


def joined(goal: str, avoided: tuple[str, ...]) -> str:
    """`goal & G !(avoided)`, or `goal` when nothing is avoided."""
    return f"{goal} & G !{disjunction(avoided)}" if avoided else goal


def variants(formula: str, keep: list[int] | None = None) -> list[str]:
    """`formula` and its variants with smaller avoid sets: with `keep` None every one with one
    proposition fewer, else for each count K the first K and the last K."""
    goal, avoided = split(formula)
    if keep is None:
        kept = list(itertools.combinations(avoided, len(avoided) - 1))
    else:
        kept = [s for k in keep if k < len(avoided)
                for s in dict.fromkeys((tuple(avoided[:k]), tuple(avoided[len(avoided) - k:])))]
    return [formula] + [joined(goal, k) for k in kept]


def subgoals(formula: str, propositions: tuple[str, ...]) -> list[str]:
    """`!(avoid) U r` for each proposition `r` of the goal (sorted)."""
    import spot

    from specrl_jax.automata.translate import parse_formula

    goal, avoided = split(formula)
    named = sorted(str(a) for a in spot.atomic_prop_collect(parse_formula(goal, propositions)))
    return [f"!{disjunction(avoided)} U {r}" for r in named if r not in avoided]


def measure(policy_ref: str, env_id: str, suite: str, episodes: int, horizon: int,
            keep: list[int] | None, with_subgoals: bool) -> dict:
    from specrl_jax.benchmark.agent import load, policy_and_params
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import evaluate
    from specrl_jax.specs import suite as suite_formulas

    world, env_params = make(env_id)
    originals = suite_formulas(suite)
    formulas = list(dict.fromkeys(v for f in originals for v in variants(f, keep)))
    policy, params = policy_and_params(load(policy_ref, env_id, seed=1, world=world), world,
                                       env_params)

    def scored(specs: list[str], steps: int | None) -> list[dict]:
        result = evaluate(policy, (world, env_params), specs, seeds=[1],
                          episodes_per_seed=episodes, policy_params=params, horizon=steps)
        per_spec = result.summary()["specs"]
        return [{"spec": f, "eta_v": round(float(per_spec[str(i)]["eta_v_mean"]), 3),
                 "eta_s": round(float(per_spec[str(i)]["eta_s_mean"]), 3),
                 "mu_acc": round(float(per_spec[str(i)]["mu_acc_mean"]), 1)}
                for i, f in enumerate(specs)]

    rows = scored(formulas, horizon)
    full = [r["eta_v"] for r in rows if r["spec"] in originals]
    smaller = [r["eta_v"] for r in rows if r["spec"] not in originals]
    value = (f"violation {np.mean(full):.3f} with the suite's avoid sets, "
             f"{np.mean(smaller):.3f} with smaller ones")
    extra = {}
    if with_subgoals:
        tasks = list(dict.fromkeys(t for f in originals
                                   for t in subgoals(f, tuple(world.propositions))))
        extra["subgoals"] = scored(tasks, None)
        value += (f"; one subgoal under the suite's avoid set violates "
                  f"{np.mean([r['eta_v'] for r in extra['subgoals']]):.3f}")
    return harness.row(f"{env_id}, {policy_ref}, {suite}: infinite specs with smaller avoid sets",
                       value, len(formulas) * episodes, episodes_per_spec=episodes,
                       horizon=horizon, specs=rows, **extra)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="PointLTL0-v0/deepltl",
                        help="a results-store cell (its seed 1), a run directory, or random")
    parser.add_argument("--env", default="PointLTL0-v0")
    parser.add_argument("--suites", nargs="+", default=["zone/infinite/per"])
    parser.add_argument("--episodes", type=int, default=100, help="episodes per spec")
    parser.add_argument("--horizon", type=int, default=10_000, help="env steps per episode")
    parser.add_argument("--keep", type=int, nargs="+", default=None,
                        help="avoided propositions kept (the first K and the last K); default: "
                             "every variant with one fewer")
    parser.add_argument("--subgoals", action="store_true",
                        help="also each goal proposition as one reach-avoid subgoal")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    for suite in args.suites:
        harness.emit(measure(args.policy, args.env, suite, args.episodes, args.horizon,
                             args.keep, args.subgoals), args.out)


if __name__ == "__main__":
    main()
