"""A hand-written LetterWorld agent scored on the benchmark: no training, it reads the automaton.

In each automaton state it takes the first one-step subgoal the compiled spec offers
(`spec.subgoal_reach[q, g]`, `spec.subgoal_avoid[q, g]`: alphabet symbols to reach and to avoid),
walks towards the nearest visible letter to reach and steps around letters to avoid; with nothing
to reach in view it moves at random. It is not a good agent, only a complete one.

    python examples/letter_subgoal_agent.py                       # 1 seed x 20 episodes, letter
    specrl-jax eval --env LetterLTL0-v0 --suite letter/finite/ind \\
        --policy letter_subgoal_agent:make_agent                  # with examples/ on PYTHONPATH
    specrl-jax bench --worlds letter --policy letter_subgoal_agent:make_agent
"""

from __future__ import annotations

import sys
from typing import Any

import jax
import jax.numpy as jnp

from specrl_jax.benchmark.agent import Agent
from specrl_jax.envs.letter import MOVES


def make_agent(world: Any) -> Agent:
    """The factory `--policy letter_subgoal_agent:make_agent` names: called once per world."""
    alphabet = jnp.asarray(world.alphabet)  # bool[A, P]: the letters of each alphabet symbol
    moves = jnp.asarray(MOVES)  # int32[4, 2]: row / column change of actions up, down, left, right

    def policy(params: Any, obs: dict, task_state: Any, key: jax.Array) -> jax.Array:
        spec, q = task_state.spec, task_state.q
        g = jnp.argmax(spec.subgoal_valid[q])  # the first valid subgoal of state q
        reach = (spec.subgoal_reach[q, g][:, None] & alphabet).any(0)  # bool[P] letters to reach
        avoid = (spec.subgoal_avoid[q, g][:, None] & alphabet).any(0)  # bool[P] letters to avoid
        ap = obs["ap"].astype(bool)  # bool[V, V, P], the agent at the centre
        view = ap.shape[0]
        centre = view // 2
        rows, cols = jnp.meshgrid(jnp.arange(view), jnp.arange(view), indexing="ij")
        targets = (ap & reach).any(-1)
        distance = jnp.where(targets, jnp.abs(rows - centre) + jnp.abs(cols - centre), 10 * view)
        target = jnp.unravel_index(jnp.argmin(distance), (view, view))
        after = centre + moves  # int32[4, 2]: the cell each action leads to
        remaining = jnp.abs(after[:, 0] - target[0]) + jnp.abs(after[:, 1] - target[1])
        blocked = (ap[after[:, 0], after[:, 1]] & avoid).any(-1)
        greedy = jnp.argmin(remaining + 100 * blocked).astype(jnp.int32)
        wander = jax.random.randint(key, (), 0, 4, jnp.int32)
        return jnp.where(targets.any(), greedy, wander)

    return Agent(policy, name="subgoal-greedy", worlds=("letter",), epsilon=False)


def main() -> int:
    from specrl_jax.benchmark import bench
    from specrl_jax.envs.registry import make

    world, _ = make("LetterLTL0-v0")
    report = bench.score(make_agent(world), worlds=("letter",), seeds=1, episodes=20,
                         out="bench_letter_subgoal_agent")  # prints one summary line per world
    print(f"wrote {report.out}/: results.json, metrics.csv, tables.md, bench.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
