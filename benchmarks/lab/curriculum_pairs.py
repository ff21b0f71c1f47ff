"""Which reach-avoid pairs does a trained policy fail? Every depth-1 task of the Zone curriculum.

The Zone curriculum's reach-avoid stage trains every pair "reach `r` while avoiding `a`" over
the world's propositions (`r != a`) and advances at a mean success of 0.95. This script scores a
policy (a results-store cell, its seed 1; a run directory; or `random`) on each pair as the
formula `!a U r` with the method's own test-time agent, `--episodes` episodes of the world's
horizon each, and groups the pairs by kind: on the grippers-and-arm Arm (`arm_*` / `grippers_*`)
whether `r` and `a` are arm or gripper propositions and of one colour or two. One JSON row
(`benchmarks/harness.py`; appended to `--out` if given) with each pair's success and violation
and each group's means: which pairs hold a stage's mean below its threshold.

    python benchmarks/lab/curriculum_pairs.py --policy PandaLTLReach1Joints-v0/deepltl --episodes 8
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
from collections import defaultdict

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness


def pair_kind(reach: str, avoid: str) -> str:
    """'grippers/arm, two colours' for `grippers_blue` / `arm_green`; 'colours' in worlds
    whose propositions have no body prefix."""
    if "_" not in reach or "_" not in avoid:
        return "colours"
    (r_body, r_colour), (a_body, a_colour) = reach.split("_", 1), avoid.split("_", 1)
    colours = "one colour" if r_colour == a_colour else "two colours"
    return f"{r_body}/{a_body}, {colours}"


def measure(policy_ref: str, env_id: str, episodes: int) -> dict:
    from specrl_jax.benchmark.agent import load, policy_and_params
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import evaluate

    world, env_params = make(env_id)
    pairs = list(itertools.permutations(world.propositions, 2))
    formulas = [f"!{avoid} U {reach}" for reach, avoid in pairs]
    policy, params = policy_and_params(load(policy_ref, env_id, seed=1, world=world), world,
                                       env_params)
    result = evaluate(policy, (world, env_params), formulas, seeds=[1],
                      episodes_per_seed=episodes, policy_params=params)
    per_spec = result.summary()["specs"]
    rows, groups = [], defaultdict(list)
    for i, (reach, avoid) in enumerate(pairs):
        s, v = (float(per_spec[str(i)][f"{m}_mean"]) for m in ("eta_s", "eta_v"))
        rows.append({"reach": reach, "avoid": avoid, "eta_s": round(s, 3), "eta_v": round(v, 3)})
        groups[pair_kind(reach, avoid)].append(s)
    by_kind = {k: {"pairs": len(v), "eta_s": round(float(np.mean(v)), 3)}
               for k, v in sorted(groups.items())}
    mean = float(np.mean([r["eta_s"] for r in rows]))
    value = f"success {mean:.3f} over {len(pairs)} pairs; " + "; ".join(
        f"{k} {g['eta_s']:.3f} ({g['pairs']})" for k, g in by_kind.items())
    return harness.row(f"{env_id}, {policy_ref}: every depth-1 reach-avoid pair", value,
                       len(pairs) * episodes, episodes_per_pair=episodes, groups=by_kind,
                       pairs=rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="PandaLTLReach1Joints-v0/deepltl",
                        help="a results-store cell (its seed 1), a run directory, or random")
    parser.add_argument("--env", default="PandaLTLReach1Joints-v0")
    parser.add_argument("--episodes", type=int, default=8, help="episodes per pair")
    parser.add_argument("--out", default=None, help="append the JSON row to this file")
    args = parser.parse_args()
    harness.emit(measure(args.policy, args.env, args.episodes), args.out)


if __name__ == "__main__":
    main()
