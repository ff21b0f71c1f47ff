"""The multi-agent coordinator with mode actions (the grid's) against sampled ones (what DeepLTL's
single-agent infinite suites use): does the action mode move a coordinator cell's violations?

For each coordinator cell of the results store (its method's stored seed-1 parameters on every
agent), this script evaluates `--suites` with both action modes over `--seeds` evaluation seeds
x `--episodes` episodes per spec (each suite's own horizon, unless `--horizon`), and prints one
JSON row per cell and suite (`benchmarks/harness.py`; appended to `--out` if given): each mode's
violation rate (over the suite and per spec) and mean accepting visits.

    python benchmarks/lab/coordinator_actions.py --cells 'PointLTL0MA2-v0/deepltl+coordinator' \\
        --suites multi_agent_zone/infinite/per --seeds 1 --episodes 8
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness


def measure(cell_name: str, suite: str, seeds: int, episodes: int,
            horizon: int | None = None) -> dict:
    from specrl_jax.benchmark import grid
    from specrl_jax.benchmark.reproduce import evaluate_coordinator
    from specrl_jax.benchmark.store import Store

    cell = dataclasses.replace(grid.cell(cell_name), seeds=seeds, episodes=episodes)
    params = Store().load_params(grid.cell(cell.params_from))
    modes = {}
    for name, deterministic in (("mode", True), ("sampled", False)):
        (result,) = evaluate_coordinator(cell, params, [suite], log=lambda line: None,
                                         deterministic=deterministic, horizon=horizon)
        summary = result.result.summary({"all": list(range(len(result.result.spec_names)))})
        modes[name] = {
            "eta_v": round(float(summary["groups"]["all"]["eta_v_mean"]), 3),
            "mu_acc": round(float(summary["groups"]["all"]["mu_acc_mean"]), 1),
            "eta_v_per_spec": [round(float(s["eta_v_mean"]), 3) for s in summary["specs"].values()],
        }
    value = (f"violation {modes['mode']['eta_v']:.3f} with mode actions, "
             f"{modes['sampled']['eta_v']:.3f} sampled; accepting visits "
             f"{modes['mode']['mu_acc']:.0f} / {modes['sampled']['mu_acc']:.0f}")
    return harness.row(f"{cell_name}, {suite}: the coordinator's agents on mode against sampled "
                       "actions", value, seeds * episodes, seeds=seeds, episodes_per_spec=episodes,
                       horizon=horizon or result.result.horizon, **modes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=["PointLTL0MA2-v0/deepltl+coordinator",
                                                       "PointLTL0MA2-v0/genz+coordinator"])
    parser.add_argument("--suites", nargs="+", default=["multi_agent_zone/infinite/per"])
    parser.add_argument("--seeds", type=int, default=1, help="evaluation seeds 1..N")
    parser.add_argument("--episodes", type=int, default=8, help="episodes per spec and seed")
    parser.add_argument("--horizon", type=int, default=None,
                        help="env steps per episode (default: each suite's own)")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    for cell in args.cells:
        for suite in args.suites:
            harness.emit(measure(cell, suite, args.seeds, args.episodes, args.horizon), args.out)


if __name__ == "__main__":
    main()
