"""How many arms need MuJoCo's collision and constraint solve, step by step, under a policy.

The arm's physics runs the collision and solve only for the arms within reach of the table or
floor, gathered into a sub-batch of 1/8 or 1/4 of the batch, the larger one in turn while more
need it (`envs/arm/physics.py`, `envs/compaction.py`); an arm with more than two contact pairs
within reach runs over all pairs, 1/64 of the batch at a time. So an evaluation's time per env
step depends on where the policy takes the arms. This script runs a policy (a results-store cell,
its seed 1, or `random`) on each suite for `--episodes` episodes per spec and `--steps` env
steps, counts the needing arms at every physics substep, and prints one JSON row per suite
(`benchmarks/harness.py`; appended to `--out` if given): the mean share of the batch needing the
solve over each quarter of the episode, the largest share, the share of substeps at which
the gathered solve ran more than one sub-batch, and the largest share of arms with more than two
contact pairs within reach.

    python benchmarks/lab/arm_solver_load.py --policy PandaLTLReach0Joints-v0/genz \
        --suites arm_grippers/finite/ind arm_grippers/infinite/per --episodes 16 --steps 400
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import defaultdict

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

from specrl_jax.envs import compaction
from specrl_jax.envs.arm import physics as arm_physics

#: per gathered function (its `needs`), the (needing, batch) count of every call, in call order
counts: dict[str, list[tuple[int, int]]] = defaultdict(list)


def counting(run_batch):
    """`compaction._run_batch` that also records, on the host, how many items need `fn`."""
    def run(fn, needs, default, capacities, x, axes):
        need = jax.vmap(lambda item: compaction._need(needs, item), in_axes=(axes,))(x)
        name = needs.__name__
        jax.debug.callback(lambda n, b: counts[name].append((int(n), int(b))),
                           need.sum(), need.shape[0])
        return run_batch(fn, needs, default, capacities, x, axes)
    return run


def measure(policy_ref: str, env_id: str, suite: str, episodes: int, steps: int) -> dict:
    from specrl_jax.benchmark.agent import load, policy_and_params
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import make_evaluator, prepare_specs
    from specrl_jax.specs import suite as suite_formulas
    from specrl_jax.tasks import TaskEnv

    world, env_params = make(env_id)
    stacked, names = prepare_specs(world, list(suite_formulas(suite)))
    policy, params = policy_and_params(load(policy_ref, env_id, seed=1, world=world), world,
                                       env_params)
    counts.clear()
    evaluator = make_evaluator(policy, TaskEnv(world, stacked), env_params, episodes, steps)
    jax.block_until_ready(evaluator(params, jnp.asarray([1], jnp.uint32)))
    table = np.asarray(counts.pop("_needs_nearest_pairs", counts.pop("_needs_solver", [])))
    overflow = np.asarray(counts.pop("<lambda>", [(0, 1)]))  # more than two pairs within reach
    share = table[:, 0] / table[:, 1]
    quarters = [round(float(q.mean()), 3) for q in np.array_split(share, 4)]
    slots = np.ceil(max(arm_physics.SOLVE_CAPACITIES) * table[:, 1])
    value = (f"share of arms needing the solve by quarter of the episode {quarters}, largest "
             f"{share.max():.3f}; more than one sub-batch at {np.mean(table[:, 0] > slots):.3f} "
             f"of substeps; more than two contact pairs within reach (all pairs solved): largest "
             f"share {np.max(overflow[:, 0] / overflow[:, 1]):.3f}")
    return harness.row(f"{env_id}, {policy_ref}, {suite}: arms needing the constraint solve",
                       value, int(table[0, 1]), episodes_per_spec=episodes, steps=steps,
                       specs=len(names), quarters=quarters, largest=float(share.max()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="PandaLTLReach0Joints-v0/genz",
                        help="a results-store cell (its seed 1), a run directory, or random")
    parser.add_argument("--env", default="PandaLTLReach0Joints-v0")
    parser.add_argument("--suites", nargs="+",
                        default=["arm_grippers/finite/ind", "arm_grippers/infinite/per"])
    parser.add_argument("--episodes", type=int, default=16, help="episodes per spec")
    parser.add_argument("--steps", type=int, default=400, help="env steps per episode")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    compaction._run_batch = counting(compaction._run_batch)  # this process only
    for suite in args.suites:
        harness.emit(measure(args.policy, args.env, suite, args.episodes, args.steps), args.out)


if __name__ == "__main__":
    main()
