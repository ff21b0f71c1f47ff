"""Where GCRL-LTL's finite-suite episodes end: success, violation, the world's own termination
(a Zone wall) or the time limit, under test-time variants of the agent.

Variants: the reference agent (mode primitive choice, safety rule at 0.85, primitives at the
test temperature 1.5), the safety rule off (threshold 2: critic values never exceed it),
sampled primitive choice, the primitives at the training temperature 1.25, mode actions (the
original's `deterministic=True`; on LetterWorld the reference agent samples), the original's search
as coded (`gcrl.make_policy(planner="as_coded")`: fewest steps, wider avoid sets), alone and with
mode actions. Reads the parameters
that `train_baselines.py` writes (`<out>/gcrl/params.msgpack`, leading seed axis).

Example (GPU, after `train_baselines.py --methods gcrl --env PointLTL0-v0 --out /tmp/zone`):
    python benchmarks/gcrl_outcomes.py /tmp/zone/gcrl/params.msgpack --seeds 5 --episodes 100
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from specrl_jax.baselines import experiment
from specrl_jax.eval.metrics import EpisodeTable

VARIANTS = {
    "reference": {},
    "no safety rule": {"value_threshold": 2.0},
    "sampled choice": {"deterministic": False},
    "training temperature 1.25": {"temperature": 1.25},
    "mode actions": {"deterministic": True},
    "as-coded planner": {"planner": "as_coded"},
    "as-coded planner, mode actions": {"planner": "as_coded", "deterministic": True},
}


def outcomes(table: EpisodeTable, horizon: int) -> dict[str, float]:
    """Fractions of episodes (all seeds and specs) by how they ended; `wall` = neither success
    nor violation before the horizon (the world terminated it); the std over seeds of eta_s and
    eta_v."""
    success, violation = np.asarray(table.success), np.asarray(table.violation)
    other = ~success & ~violation
    ended_early = np.asarray(table.steps) < horizon
    per_seed = lambda x: x.reshape(x.shape[0], -1).mean(axis=1)  # [seeds, specs, episodes]
    return {"success": float(success.mean()), "violation": float(violation.mean()),
            "wall": float((other & ended_early).mean()),
            "timeout": float((other & ~ended_early).mean()),
            "success_seed_std": float(per_seed(success).std()),
            "violation_seed_std": float(per_seed(violation).std())}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("params", help="params.msgpack of a GCRL-LTL run (leading seed axis)")
    parser.add_argument("--env", default="PointLTL0-v0")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--suites", nargs="+", default=None, help="default: the finite suites")
    parser.add_argument("--horizon", type=int, default=None, help="default: the world's")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = parser.parse_args()

    suites = args.suites or [s for s in experiment.suites_for(args.env) if "/finite/" in s]
    params = experiment.load_params("gcrl", args.env, args.params, args.seeds)
    rows = []
    for name in args.variants:
        options = VARIANTS[name]
        results = experiment.evaluate("gcrl", args.env, params, suites, args.episodes,
                                      log=lambda _: None, horizon=args.horizon, **options)
        for r in results:
            row = {"variant": name, "suite": r.suite,
                   **outcomes(r.result.table, r.result.horizon)}
            rows.append(row)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
