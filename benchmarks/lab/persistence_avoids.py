"""Persistence with one avoided colour fewer: do a policy's violations come from the size of the
avoid set (the curricula train reach-stay with at most two avoided colours) or from staying?

For each spec `F G x & G !(a | b | c)` of a persistence suite, this script also evaluates every
variant that avoids one colour fewer, `F G x & G !(a | b)` and so on, with a policy (a
results-store cell, its seed 1, or `random`) over `--episodes` episodes of `--horizon` steps,
and prints one JSON row per suite (`benchmarks/harness.py`; appended to `--out` if given): each
spec's violation rate and mean accepting visits. With the method's own test-time agent (sampled
actions on infinite specs, as in the suites).

    python benchmarks/lab/persistence_avoids.py --policy PointLTL0-v0/deepltl --episodes 100
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness


def variants(formula: str) -> list[str]:
    """`formula` (`F G x & G !(a | b | ...)`) and each variant that avoids one colour fewer."""
    reach, avoid = formula.split(" & G !")
    colours = avoid.strip("()").split(" | ")
    fewer = [" | ".join(kept) for kept in itertools.combinations(colours, len(colours) - 1)]
    return [formula] + [f"{reach} & G !{f'({k})' if ' | ' in k else k}" for k in fewer]


def measure(policy_ref: str, env_id: str, suite: str, episodes: int, horizon: int) -> dict:
    from specrl_jax.benchmark.agent import load, policy_and_params
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import evaluate
    from specrl_jax.specs import suite as suite_formulas

    world, env_params = make(env_id)
    formulas = [v for f in suite_formulas(suite) for v in variants(f)]
    policy, params = policy_and_params(load(policy_ref, env_id, seed=1, world=world), world,
                                       env_params)
    result = evaluate(policy, (world, env_params), formulas, seeds=[1],
                      episodes_per_seed=episodes, policy_params=params, horizon=horizon)
    per_spec = result.summary()["specs"]
    rows = [{"spec": f, "eta_v": round(float(per_spec[str(i)]["eta_v_mean"]), 3),
             "mu_acc": round(float(per_spec[str(i)]["mu_acc_mean"]), 1)}
            for i, f in enumerate(formulas)]
    full = [r["eta_v"] for r in rows if r["spec"] in suite_formulas(suite)]
    fewer = [r["eta_v"] for r in rows if r["spec"] not in suite_formulas(suite)]
    value = (f"violation {np.mean(full):.3f} with the suite's avoid sets, {np.mean(fewer):.3f} "
             "with one colour fewer")
    return harness.row(f"{env_id}, {policy_ref}, {suite}: persistence with one avoided colour "
                       "fewer", value, len(formulas) * episodes, episodes_per_spec=episodes,
                       horizon=horizon, specs=rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="PointLTL0-v0/deepltl",
                        help="a results-store cell (its seed 1), a run directory, or random")
    parser.add_argument("--env", default="PointLTL0-v0")
    parser.add_argument("--suites", nargs="+", default=["zone/infinite/per"])
    parser.add_argument("--episodes", type=int, default=100, help="episodes per spec")
    parser.add_argument("--horizon", type=int, default=10_000, help="env steps per episode")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    for suite in args.suites:
        harness.emit(measure(args.policy, args.env, suite, args.episodes, args.horizon), args.out)


if __name__ == "__main__":
    main()
