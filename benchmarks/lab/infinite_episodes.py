"""One recorded episode per method and infinite suite on a static Zone world, with the stored cells'
seed-1 parameters: accepting visits against time, and where the agent goes on the persistence task
(the path figure draws the zones where they start, so it suits worlds whose zones stay there).

For each `--methods` cell of `--env` in the results store, the first formula of each `--suites`
suite runs one episode of `--horizon` steps from the same reset key (every method meets the same
layout per suite), through the method's test-time agent as the evaluation runs it (sampled
actions on infinite tasks). Per step it keeps only the agent's xy, the accepting visits so far and
the violation flag (`eval.record_episodes(capture=...)`). Writes a JSON summary (visits every
`--every` steps, final visits, the step of a violation; `--summary`), one result row (`--out`,
`benchmarks/harness.py`) and two figures:
accepting visits over time (one panel per suite, one line per method) and the persistence
episode's path on the arena (one panel per method).

    python benchmarks/lab/infinite_episodes.py --methods genz deepltl \\
        --summary benchmarks/results/pointltl0_infinite_episodes.json \\
        --plot-visits docs/figures/infinite_accepting_visits_point.png \\
        --plot-paths docs/figures/persistence_trajectories_point.png
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

PERSISTENCE = "zone/infinite/per"


def record(env_id: str, method: str, suites: list[str], horizon: int, seed: int
           ) -> dict[str, Any]:
    """One episode per suite (its first formula) for the `env_id/method` cell's seed 1: xy
    `[T + 1, 2]`, accepting visits `[T + 1]`, violation `[T + 1]`, steps alive, the zones."""
    from specrl_jax import automata, specs
    from specrl_jax.benchmark.agent import load, policy_and_params
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import record_episodes
    from specrl_jax.tasks import TaskEnv

    world, env_params = make(env_id)
    policy, params = policy_and_params(load(f"{env_id}/{method}", env_id, seed=1, world=world),
                                       world, env_params)
    formulas = [specs.suite(s)[0] for s in suites]
    task = TaskEnv(world, automata.stack([
        automata.compile_spec(f, world.propositions, alphabet=world.alphabet) for f in formulas]))
    keys = jnp.stack([jax.random.key(seed)] * len(suites))
    index = jnp.arange(len(suites), dtype=jnp.int32)
    start = time.perf_counter()
    (xy, visits, violation), alive = jax.device_get(record_episodes(
        policy, task, env_params, keys, index, policy_params=params, horizon=horizon,
        capture=lambda s: (s.env_state.physics.agent_pos[:2], s.num_accepting, s.violation)))
    wall = time.perf_counter() - start
    _, first = task.reset(jax.random.split(keys[0], 3)[0], env_params, index[0])
    layout = jax.device_get(world.layout(first.env_state))
    zones = {"xy": np.asarray(layout["zone_xy"], float).round(3).tolist(),
             "colour": [world.propositions[int(c)] for c in layout["zone_color"]],
             "radius": np.asarray(layout["zone_radius"], float).round(3).tolist()}
    episodes = {}
    for i, suite in enumerate(suites):
        steps = int(np.asarray(alive[i]).sum()) - 1
        violated = np.flatnonzero(np.asarray(violation[i]))
        episodes[suite] = {"formula": formulas[i], "steps": steps,
                           "xy": np.asarray(xy[i, :steps + 1], float),
                           "visits": np.asarray(visits[i, :steps + 1], int),
                           "violation_step": int(violated[0]) if violated.size else None}
    return {"episodes": episodes, "zones": zones, "wall_s": wall}


def summary(recorded: dict[str, dict[str, Any]], every: int) -> dict[str, Any]:
    """The JSON-ready part: per method and suite the formula, steps, final visits, violation step
    and the visits every `every` steps; the persistence episode's path every `every` steps."""
    out = {}
    for method, rec in recorded.items():
        out[method] = {"zones": rec["zones"], "record_s": round(rec["wall_s"], 1), "suites": {}}
        for suite, ep in rec["episodes"].items():
            out[method]["suites"][suite] = {
                "formula": ep["formula"], "steps": ep["steps"],
                "accepting_visits": int(ep["visits"][-1]),
                "violation_step": ep["violation_step"],
                "visits_every": ep["visits"][::every].tolist(),
                **({"xy_every": ep["xy"][::every].round(3).tolist()} if suite == PERSISTENCE
                   else {})}
    return out


def plot_visits(recorded: dict[str, dict[str, Any]], suites: list[str], env_id: str,
                path: str) -> None:
    """Accepting visits over time: one panel per suite, one line per method (x: a violation)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from specrl_jax.benchmark.report import METHOD_NAMES

    fig, axes = plt.subplots(1, len(suites), figsize=(4.2 * len(suites), 3.2),
                             layout="constrained")
    for ax, suite in zip(np.atleast_1d(axes), suites):
        for method, rec in recorded.items():
            ep = rec["episodes"][suite]
            line, = ax.plot(ep["visits"], label=METHOD_NAMES.get(method, method), linewidth=1.2)
            if ep["violation_step"] is not None:
                ax.plot(ep["violation_step"], ep["visits"][ep["violation_step"]], "x",
                        color=line.get_color(), markersize=8)
        ax.set_title(f"{suite}\n{next(iter(recorded.values()))['episodes'][suite]['formula']}",
                     fontsize=7)
        ax.set_xlabel("step", fontsize=8)
        ax.set_ylabel("accepting visits", fontsize=8)
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.suptitle(f"{env_id}: one episode per method and suite (seed-1 parameters; x: violation)",
                 fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_paths(recorded: dict[str, dict[str, Any]], env_id: str, path: str) -> None:
    """The persistence episode's path on the arena, one panel per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from specrl_jax.benchmark.report import METHOD_NAMES, draw_arena

    fig, axes = plt.subplots(1, len(recorded), figsize=(3.4 * len(recorded), 3.6),
                             layout="constrained")
    for ax, (method, rec) in zip(np.atleast_1d(axes), recorded.items()):
        zones = rec["zones"]
        draw_arena(ax, zones["xy"], zones["colour"], zones["radius"])
        ep = rec["episodes"][PERSISTENCE]
        ax.plot(ep["xy"][:, 0], ep["xy"][:, 1], "k", linewidth=0.6)
        ax.plot(*ep["xy"][0], "ko", markersize=3)
        if ep["violation_step"] is not None:
            ax.plot(*ep["xy"][ep["violation_step"]], "rx", markersize=8)
        outcome = (f"violation at step {ep['violation_step']}" if ep["violation_step"] is not None
                   else f"{ep['visits'][-1]} accepting visits in {ep['steps']} steps")
        ax.set_title(f"{METHOD_NAMES.get(method, method)}\n{outcome}", fontsize=8)
    formula = next(iter(recorded.values()))["episodes"][PERSISTENCE]["formula"]
    fig.suptitle(f"{env_id}: {formula} (seed-1 parameters, one episode)", fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PointLTL0-v0")
    parser.add_argument("--methods", nargs="+", default=["genz", "deepltl"],
                        help="cells of --env with stored parameters (GCRL-LTL's keep none)")
    parser.add_argument("--suites", nargs="+",
                        default=["zone/infinite/rsp", "zone/infinite/rec", PERSISTENCE])
    parser.add_argument("--horizon", type=int, default=10_000, help="env steps per episode")
    parser.add_argument("--seed", type=int, default=2026, help="the episodes' reset key")
    parser.add_argument("--every", type=int, default=50, help="keep every N-th step in the JSON")
    parser.add_argument("--summary", default=None, help="write the JSON summary here")
    parser.add_argument("--out", default=None, help="append the result row to this file")
    parser.add_argument("--plot-visits", default=None, help="accepting visits figure (PNG)")
    parser.add_argument("--plot-paths", default=None, help="persistence paths figure (PNG)")
    args = parser.parse_args()
    if PERSISTENCE not in args.suites and args.plot_paths:
        parser.error(f"--plot-paths draws the {PERSISTENCE} episode: add it to --suites")
    recorded = {m: record(args.env, m, args.suites, args.horizon, args.seed)
                for m in args.methods}
    result = summary(recorded, args.every)
    if args.summary:
        with open(args.summary, "w") as f:
            json.dump({"env": args.env, "horizon": args.horizon, "seed": args.seed,
                       "every": args.every, "methods": result}, f)
    if args.plot_visits:
        plot_visits(recorded, args.suites, args.env, args.plot_visits)
    if args.plot_paths:
        plot_paths(recorded, args.env, args.plot_paths)
    value = "; ".join(
        f"{m}: " + ", ".join(f"{s.rsplit('/', 1)[-1]} {r['accepting_visits']}"
                             + (f" (violation at {r['violation_step']})"
                                if r["violation_step"] is not None else "")
                             for s, r in result[m]["suites"].items())
        for m in args.methods)
    harness.emit(harness.row(f"{args.env}: accepting visits of one {args.horizon}-step episode "
                             "per method and suite, seed-1 parameters", value, len(args.suites)),
                 args.out)


if __name__ == "__main__":
    main()
