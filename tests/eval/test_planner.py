"""The LetterWorld planner against brute-force breadth-first search on small maps."""

from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from eval.tiny_world import MOVES, TinyParams, TinyWorld, hand_spec, reach_avoid_spec, stack_specs

from specrl_jax.eval.evaluate import evaluate, record_episodes
from specrl_jax.eval.planner import UNREACHABLE, distance_table, oracle_policy
from specrl_jax.tasks import TaskEnv


def bfs_steps(spec, letters: np.ndarray, q0: int, cell0: tuple[int, int]) -> int:
    """Fewest moves from (q0, cell0) to an accepting or success-entering transition, never
    entering a violating state; UNREACHABLE if none (plain BFS over cells x states)."""
    delta, accepting = np.asarray(spec.delta), np.asarray(spec.accepting)
    success, violation = np.asarray(spec.success), np.asarray(spec.violation)
    n = letters.shape[0]
    seen = {(q0, cell0)}
    frontier = deque([(q0, cell0, 0)])
    while frontier:
        q, (r, c), depth = frontier.popleft()
        for dr, dc in MOVES:
            cell = ((r + dr) % n, (c + dc) % n)
            symbol = int(letters[cell]) + 1
            q_next = int(delta[q, symbol])
            if accepting[q, symbol] or success[q_next]:
                return depth + 1
            if violation[q_next] or (q_next, cell) in seen:
                continue
            seen.add((q_next, cell))
            frontier.append((q_next, cell, depth + 1))
    return UNREACHABLE


def random_letters(rng: np.random.Generator, n: int = 5, count: int = 3) -> np.ndarray:
    letters = np.full(n * n, -1, np.int8)
    cells = 1 + rng.permutation(n * n - 1)[:count]
    letters[cells] = np.arange(count)
    return letters.reshape(n, n)


def walls_spec():
    """`!c U b` with c in a wall-like role; b must be reached avoiding every c."""
    return hand_spec([[0, 0, 1, 2], [1, 1, 1, 1], [2, 2, 2, 2]],
                     accepting_into=(1,), success=(1,), violation=(2,))


@pytest.mark.parametrize("make_spec", [reach_avoid_spec, walls_spec])
def test_distance_table_matches_bfs(make_spec):
    spec = make_spec()
    table = jax.jit(distance_table)
    rng = np.random.default_rng(0)
    for letters in [random_letters(rng) for _ in range(3)]:
        dist = np.asarray(table(spec, jnp.asarray(letters)))
        expected = np.array([[[bfs_steps(spec, letters, q, (r, c)) for c in range(5)]
                              for r in range(5)] for q in range(dist.shape[0])])
        np.testing.assert_array_equal(dist, expected)


def test_unreachable_when_the_avoid_set_encloses_the_goal():
    # b at (2, 2) walled in by c on all four sides: `!c U b` cannot be satisfied
    letters = np.full((5, 5), -1, np.int8)
    letters[2, 2] = 1
    for cell in [(1, 2), (3, 2), (2, 1), (2, 3)]:
        letters[cell] = 2
    dist = np.asarray(distance_table(walls_spec(), jnp.asarray(letters)))
    assert dist[0, 0, 0] == UNREACHABLE == bfs_steps(walls_spec(), letters, 0, (0, 0))
    assert dist[0, 1, 2] == 1  # standing on a c cell, one step from b


def test_oracle_succeeds_in_the_fewest_steps():
    env = TinyWorld()
    params = TinyParams(max_steps=20)
    specs = stack_specs([reach_avoid_spec(), walls_spec()])
    result = evaluate(oracle_policy(env), (env, params), specs, seeds=[1, 2], episodes_per_seed=8)
    assert result.table.success.all() and not result.table.violation.any()
    # the steps of every episode equal the BFS optimum on its map
    task = TaskEnv(env, specs)
    keys = jax.random.split(jax.random.key(7), 6)
    index = jnp.arange(6) % 2
    states, alive = record_episodes(oracle_policy(env), task, params, keys, index)
    for i in range(6):
        letters = np.asarray(states.env_state.letters[i, 0])
        spec = jax.tree.map(lambda x, k=int(index[i]): x[k], specs)
        assert int(alive[i].sum()) - 1 == bfs_steps(spec, letters, 0, (0, 0))
        assert bool(states.success[i, -1])


def test_oracle_rejects_other_worlds():
    class NotAGrid:
        action_space = None

    with pytest.raises(ValueError, match="LetterWorld"):
        oracle_policy(NotAGrid())
