"""An optimal planner for LetterWorld: shortest satisfying paths on the product grid x automaton.

At every episode start the planner reads the map (`letters int8[N, N]`, -1 empty) and computes,
by value iteration inside `jit`, the table `dist int32[S, N, N]`: the fewest steps from automaton
state `q` with the agent on cell `(r, c)` to a *goal transition*, one that is accepting or enters
a success state, without ever entering a violating state. Moves are the world's four actions on
the torus; the label after a move is the letter of the target cell. Each step then takes the action
of least `1 + dist` at the successor (ties to the lowest action index), so on a finite
(co-safe) spec it follows a shortest satisfying path and reaches `eta_s = 1`, `eta_v = 0` whenever
one exists within the horizon: the "optimal steps" reference line of the reports.

On infinite-horizon specs the same table walks to the nearest next accepting transition, a
greedy heuristic, not an optimum of `mu_acc`. Epsilon edges are never taken.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from specrl_jax.automata import label_symbol
from specrl_jax.tasks.policy import StatefulPolicy

UNREACHABLE = 1 << 20
# (row, col) offsets of the actions up, down, left, right.
MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))


def symbol_grid(letters: jax.Array, alphabet: jax.Array) -> jax.Array:
    """int32[N, N]: the alphabet row of the label on each cell.

    Args:
        letters: int8[N, N], letter index per cell, -1 when empty.
        alphabet: bool[A, P], the proposition assignments of the spec's alphabet.
    """
    num_props = alphabet.shape[1]
    props = letters[..., None] == jnp.arange(num_props, dtype=letters.dtype)  # [N, N, P]
    return label_symbol(alphabet, props)


def _shift(grid: jax.Array, move: tuple[int, int]) -> jax.Array:
    """`out[..., r, c] = grid[..., r + dr, c + dc]` on the torus."""
    return jnp.roll(grid, (-move[0], -move[1]), axis=(-2, -1))


def _transitions(spec: Any, symbols: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """For every (q, action, r, c): next state, goal transition, violating transition."""
    target_symbols = jnp.stack([_shift(symbols, m) for m in MOVES])  # [4, N, N]
    q_next = spec.delta[:, target_symbols]  # [S, 4, N, N]
    goal = spec.accepting[:, target_symbols] | spec.success[q_next]
    bad = spec.violation[q_next] & ~goal
    return q_next, goal, bad


def _action_costs(dist: jax.Array, q_next: jax.Array, goal: jax.Array, bad: jax.Array) -> jax.Array:
    """int32[S, 4, N, N]: steps to a goal transition when taking each action first."""
    dist_moved = jnp.stack([_shift(dist, m) for m in MOVES], axis=1)  # [S, 4, N, N]
    dist_next = jnp.take_along_axis(dist_moved, q_next, axis=0)
    cost = jnp.where(goal, 1, jnp.minimum(dist_next + 1, UNREACHABLE))
    return jnp.where(bad, 2 * UNREACHABLE, cost)


def distance_table(spec: Any, letters: jax.Array) -> jax.Array:
    """int32[S, N, N]: fewest steps from (q, cell) to a goal transition; `UNREACHABLE` if none.

    Args:
        spec: one CompiledSpec (delta int32[S, A], accepting bool[S, A], success/violation bool[S]).
        letters: int8[N, N], the map (-1 empty).
    """
    q_next, goal, bad = _transitions(spec, symbol_grid(letters, spec.alphabet))
    num_states, _, n, _ = q_next.shape
    init = jnp.full((num_states, n, n), UNREACHABLE, jnp.int32)

    def improve(loop):
        dist, _, iteration = loop
        new = jnp.minimum(_action_costs(dist, q_next, goal, bad).min(axis=1), UNREACHABLE)
        return new, jnp.any(new != dist), iteration + 1

    def not_converged(loop):
        _, changed, iteration = loop
        return changed & (iteration <= num_states * n * n)

    dist, _, _ = jax.lax.while_loop(not_converged, improve, (init, jnp.array(True), 0))
    return dist


def plan_action(spec: Any, letters: jax.Array, dist: jax.Array, q: jax.Array,
                agent: jax.Array) -> jax.Array:
    """int32[]: the first action of a shortest path to a goal transition from (q, agent)."""
    n = letters.shape[0]
    targets = (agent[None, :] + jnp.asarray(MOVES)) % n  # [4, 2]
    target_letters = letters[targets[:, 0], targets[:, 1]]
    symbols = symbol_grid(target_letters[None], spec.alphabet)[0]  # [4]
    q_next = spec.delta[q, symbols]
    goal = spec.accepting[q, symbols] | spec.success[q_next]
    bad = spec.violation[q_next] & ~goal
    dist_next = dist[q_next, targets[:, 0], targets[:, 1]]
    cost = jnp.where(goal, 1, jnp.minimum(dist_next + 1, UNREACHABLE))
    return jnp.argmin(jnp.where(bad, 2 * UNREACHABLE, cost)).astype(jnp.int32)


def _check_letter_world(env: Any) -> None:
    config = getattr(env, "config", None)
    n = getattr(getattr(env, "action_space", None), "n", None)
    if not hasattr(config, "grid_size") or n != len(MOVES):
        raise ValueError(
            f"the oracle planner needs LetterWorld (a torus grid with letters and 4 moves); "
            f"got {env!r}"
        )


def oracle_policy(env: Any) -> StatefulPolicy:
    """The LetterWorld planner as a `StatefulPolicy`; the carry is the distance table.

    Reads the map and the agent from `env.layout(task_state.env_state)` (`letters`, `agent`),
    and `task_state.q` and `task_state.spec`; privileged, so also complete on partial views.
    """
    _check_letter_world(env)

    def init(policy_params: Any, obs: Any, task_state: Any, key: jax.Array) -> jax.Array:
        return distance_table(task_state.spec, env.layout(task_state.env_state)["letters"])

    def apply(policy_params: Any, obs: Any, task_state: Any, dist: jax.Array, key: jax.Array):
        world = env.layout(task_state.env_state)
        action = plan_action(task_state.spec, world["letters"], dist, task_state.q, world["agent"])
        return action, dist

    return StatefulPolicy(init, apply)
