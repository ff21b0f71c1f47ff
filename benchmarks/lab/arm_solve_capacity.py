"""The arm's evaluation step under sub-batch sizes of its gathered contact solve: does a larger
sub-batch (fewer passes where many arms are near the table) shorten an evaluation?

The arm's physics runs the collision and constraint solve only for the arms within reach of the
table or floor, gathered into the smallest sub-batch of `Physics.solve_capacities` (fractions of
the batch: 1/8, 1/4 by default) that holds them, the largest one in turn while more need it
(`envs/arm/physics.py`, `envs/compaction.py`). On infinite suites a trained policy takes a
third to two thirds of the arms near the table late in the episode (`arm_solver_load.py`), so
the solve runs in several passes per substep. For each `--capacities` set this script builds the
world with it, compiles the evaluator of `--suite` for a policy (a results-store cell, its seed
1, or `random`) over `--episodes` episodes per spec and `--steps` env steps, runs it twice and
times the second run, and prints one JSON row per set (`benchmarks/harness.py`; appended to
`--out` if given): seconds per env step and whether the outcomes equal the first set's.

    python benchmarks/lab/arm_solve_capacity.py --episodes 1500 --steps 400 \\
        --capacities 0.125,0.25 0.125,0.25,0.5,1.0
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness


def run(capacities: tuple[float, ...], policy_ref: str, env_id: str, suite: str, episodes: int,
        steps: int) -> tuple[float, float, np.ndarray]:
    """(compile s, run s, per-episode success and violation) with the world's solve capacities
    set to `capacities`."""
    from specrl_jax.benchmark.agent import load, policy_and_params
    from specrl_jax.envs.arm import model as arm_model
    from specrl_jax.envs.arm.physics import Physics
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import make_evaluator, prepare_specs
    from specrl_jax.specs import suite as suite_formulas
    from specrl_jax.tasks import TaskEnv

    world, env_params = make(env_id)
    world.physics = Physics(world.mj_model, arm_model.FORCE_LIMITS, solve_capacities=capacities,
                            motor_solve=world.config.motor_solve)
    stacked, _ = prepare_specs(world, list(suite_formulas(suite)))
    policy, params = policy_and_params(load(policy_ref, env_id, seed=1, world=world), world,
                                       env_params)
    evaluator = make_evaluator(policy, TaskEnv(world, stacked), env_params, episodes, steps)
    seeds = jnp.asarray([1], jnp.uint32)
    start = time.perf_counter()
    jax.block_until_ready(evaluator(params, seeds))
    compiled = time.perf_counter() - start
    start = time.perf_counter()
    table = jax.block_until_ready(evaluator(params, seeds))
    wall = time.perf_counter() - start
    outcomes = np.stack([np.asarray(table.success), np.asarray(table.violation)])
    return compiled, wall, outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="PandaLTLReach0Joints-v0/genz",
                        help="a results-store cell (its seed 1), a run directory, or random")
    parser.add_argument("--env", default="PandaLTLReach0Joints-v0")
    parser.add_argument("--suite", default="arm_grippers/infinite/per")
    parser.add_argument("--episodes", type=int, default=1500, help="episodes per spec")
    parser.add_argument("--steps", type=int, default=400, help="env steps per episode")
    parser.add_argument("--capacities", nargs="+", default=["0.125,0.25", "0.125,0.25,0.5,1.0"],
                        help="sets of sub-batch fractions, comma-separated, the default's first")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    first = None
    for text in args.capacities:
        capacities = tuple(float(c) for c in text.split(","))
        compiled, wall, outcomes = run(capacities, args.policy, args.env, args.suite,
                                       args.episodes, args.steps)
        first = outcomes if first is None else first
        per_step = wall / args.steps
        harness.emit(harness.row(
            f"{args.env}, {args.policy}, {args.suite}: evaluation with the contact solve's "
            f"sub-batches {capacities}", f"{per_step:.4f} s per env step ({wall:.1f} s for "
            f"{args.steps} steps; compile {compiled:.1f} s)", int(outcomes.shape[1] * outcomes.shape[2]
                                                                  * outcomes.shape[3]),
            capacities=capacities, seconds_per_step=per_step, compile_s=compiled,
            same_outcomes=bool(np.array_equal(outcomes, first)), episodes_per_spec=args.episodes,
            steps=args.steps), args.out)


if __name__ == "__main__":
    main()
