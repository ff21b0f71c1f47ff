"""GCRL-LTL's value-weighted search over an automaton for the next subgoal, inside `jit`.

The original plans on a "path graph" of its Buchi automaton: a node is (automaton state, the
goal proposition that led there); an edge reaches the next goal proposition and costs
`1 - V`, where V is the policy critic's value of that goal from the current observation for
the first goal, and the goal-conditioned value function's (GCVF) value of the pair (previous
goal, next goal) after it. A plan is a lasso: a prefix to an accepting node plus a loop back to
it, weighted `prefix + OMEGA * loop`, the cheapest over the accepting strongly connected
components found by Dijkstra. Co-safe specs need no loop: the cheapest way into a success
state.

Here the same graph is built on a compiled spec (`automata.CompiledSpec`, transition-based
acceptance, epsilon edges of limit-deterministic automata):

- node `(q, g)`, `g` in `0..P-1` the last goal, `g = P` none yet; `N = S * (P + 1)` nodes;
- goal edge `(q, g) -p-> (delta[q, {p}], p)` for every proposition p whose single-proposition
  assignment is in the alphabet, cost `goal_cost[g, p]`; the empty assignment and epsilon edges
  keep the last goal and cost `HOP` (the world produces the empty label by itself);
- edges into violation states are absent, and so is a goal edge to another proposition from a
  state where the empty label is a violation (the way there crosses empty cells): once in such
  a state (e.g. after the jump of `F G a`) the agent can only stay on the proposition it is on;
- self-loops are edges only where they are accepting or the state has an epsilon edge (to stand
  on a proposition before jumping), as the original's path graph has no self-loop goals: a
  detour through an unrelated proposition would otherwise trade the critic's value of the next
  goal for the GCVF's.

Every edge costs at least `HOP`, so every cycle costs more than 0 and, among plans of equal
value, the one of fewer steps wins (the original's Dijkstra kept the first found). All-pairs
distances come from Floyd-Warshall (`cost_to_go`, once per episode: the value map is the
episode's first observation's, as the original's); the per-step choice (`first_step`) is a
one-step look-ahead over the out-edges of the current node with the current critic values.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

HOP = 1e-3  # cost of every edge on top of 1 - V: ties go to fewer steps, no free cycles
OMEGA = 5.0  # weight of the loop of a lasso (the original's)


def goal_symbols(alphabet: np.ndarray) -> tuple[np.ndarray, int]:
    """Host side: the alphabet row of each single-proposition assignment (int32[P], -1 where the
    world cannot produce it alone) and the row of the empty assignment (-1 if none)."""
    alphabet = np.asarray(alphabet, bool)
    num_props = alphabet.shape[1]
    rows = np.full(num_props, -1, np.int32)
    for p in range(num_props):
        hit = np.nonzero((alphabet == np.eye(num_props, dtype=bool)[p]).all(axis=1))[0]
        if len(hit):
            rows[p] = hit[0]
    empty = np.nonzero(~alphabet.any(axis=1))[0]
    return rows, int(empty[0]) if len(empty) else -1


def cost_matrix(start_values: jax.Array, pair_values: jax.Array,
                as_coded: bool = False) -> jax.Array:
    """Edge costs from values: float32[P + 1, P], row g < P the cost of goal p right after goal g
    (`1 - pair_values[g, p]`, 0 to stay on the same goal), row P the first goal's
    (`1 - start_values[p]`); clipped at 0 (the original's intended cost, docs/fidelity.md),
    plus `HOP`.

    `as_coded`: the original's code instead (`compute_cost`): every edge into goal p costs
    `min(1 - start_values[p], 0)` (the single-goal value whatever the previous goal, and `min`
    for `max`: 0 unless V > 1), plus `HOP`, at least 0; the search then prefers fewer steps,
    not values, and breaks ties by proposition order (the original's Dijkstra: first found).

    Args:
        start_values: float32[P], the critic's V(s, p).
        pair_values: float32[P, P], the GCVF's value of goal p after goal g.
    """
    num_props = start_values.shape[-1]
    if as_coded:
        row = jnp.maximum(jnp.minimum(1.0 - start_values, 0.0) + HOP, 0.0)  # no negative cycles
        return jnp.broadcast_to(row, (num_props + 1, num_props))
    pair = jnp.where(jnp.eye(num_props, dtype=bool), 1.0, pair_values)
    values = jnp.concatenate([pair, start_values[None]], axis=0)
    return jnp.maximum(1.0 - values, 0.0) + HOP


class Edges(NamedTuple):
    """The path graph's edges of one spec, grouped by kind (see the module docstring).

    Goal edges `[S, P]`: `goal_next` the target state, `goal_ok` the edge exists when the
    last goal is p itself, `goal_acc` it is accepting; `travel_ok` bool[S]: the empty label is
    safe in the state, so goal edges to other propositions exist too. Empty-label edges `[S]`:
    `empty_next`, `empty_ok`, `empty_acc`. Epsilon edges `[S, E]`: `eps_next`, `eps_ok`.
    """

    goal_next: jax.Array
    goal_ok: jax.Array
    goal_acc: jax.Array
    travel_ok: jax.Array
    empty_next: jax.Array
    empty_ok: jax.Array
    empty_acc: jax.Array
    eps_next: jax.Array
    eps_ok: jax.Array


def edges(spec, goal_syms: jax.Array, empty_sym: int) -> Edges:
    """The edges of one (unstacked) spec's path graph; `goal_syms`, `empty_sym` from
    `goal_symbols`."""
    live = ~spec.violation
    states = jnp.arange(spec.delta.shape[0])
    jumps = spec.epsilon[:, 0] >= 0  # [S]: the state has an epsilon edge
    sym = jnp.maximum(goal_syms, 0)
    goal_next = spec.delta[:, sym]  # [S, P]
    moves = (goal_next != states[:, None]) | spec.accepting[:, sym] | jumps[:, None]
    goal_ok = (goal_syms >= 0)[None] & live[:, None] & live[goal_next] & moves
    goal_acc = goal_ok & spec.accepting[:, sym]
    e = max(empty_sym, 0)
    empty_next = spec.delta[:, e]
    empty_ok = (live & live[empty_next] & (empty_sym >= 0)
                & ((empty_next != states) | spec.accepting[:, e]))
    empty_acc = empty_ok & spec.accepting[:, e]
    travel_ok = (empty_sym < 0) | live[empty_next]
    eps_next = jnp.maximum(spec.epsilon, 0)
    eps_ok = (spec.epsilon >= 0) & live[:, None] & live[eps_next]
    return Edges(goal_next, goal_ok, goal_acc, travel_ok, empty_next, empty_ok, empty_acc,
                 eps_next, eps_ok)


def _goal_mask(graph: Edges) -> jax.Array:
    """bool[S, P + 1, P]: goal edge (q, g) -p-> exists (`goal_ok`, and `travel_ok` or g == p)."""
    num_props = graph.goal_ok.shape[1]
    stay = jnp.eye(num_props + 1, num_props, dtype=bool)[None]
    return graph.goal_ok[:, None, :] & (graph.travel_ok[:, None, None] | stay)


def _weights(graph: Edges, goal_cost: jax.Array) -> jax.Array:
    """float32[N, N] edge weights (inf: no edge; the cheapest of parallel edges)."""
    num_states, num_props = graph.goal_next.shape
    width = num_props + 1
    n = num_states * width
    q = jnp.arange(num_states)[:, None, None]
    g = jnp.arange(width)[None, :, None]
    p = jnp.arange(num_props)[None, None, :]
    src = jnp.broadcast_to(q * width + g, (num_states, width, num_props))
    dst = jnp.broadcast_to(graph.goal_next[:, None, :] * width + p, src.shape)
    cost = jnp.where(_goal_mask(graph), goal_cost[None], jnp.inf)
    weights = jnp.full((n, n), jnp.inf).at[src.ravel(), dst.ravel()].min(cost.ravel())
    g1 = jnp.arange(width)[None, :]
    src = jnp.arange(num_states)[:, None] * width + g1  # [S, G]
    dst = graph.empty_next[:, None] * width + g1
    cost = jnp.where(graph.empty_ok[:, None], HOP, jnp.inf)
    weights = weights.at[src.ravel(), dst.ravel()].min(jnp.broadcast_to(cost, src.shape).ravel())
    num_slots = graph.eps_next.shape[1]
    src = jnp.broadcast_to(src[:, :, None], (num_states, width, num_slots))
    dst = graph.eps_next[:, None, :] * width + g1[..., None]
    cost = jnp.broadcast_to(jnp.where(graph.eps_ok[:, None, :], HOP, jnp.inf), src.shape)
    return weights.at[src.ravel(), dst.ravel()].min(cost.ravel())


def shortest_paths(weights: jax.Array) -> jax.Array:
    """float32[N, N] all-pairs shortest path costs (Floyd-Warshall; 0 on the diagonal)."""
    n = weights.shape[0]
    dist = jnp.where(jnp.eye(n, dtype=bool), 0.0, weights)

    def relax(k, dist):
        column = jax.lax.dynamic_slice_in_dim(dist, k, 1, axis=1)
        via = column + jax.lax.dynamic_slice_in_dim(dist, k, 1, axis=0)
        return jnp.minimum(dist, via)

    return jax.lax.fori_loop(0, n, relax, dist)


def cost_to_go(spec, goal_cost: jax.Array, goal_syms: jax.Array, empty_sym: int,
               omega: float = OMEGA) -> jax.Array:
    """float32[N]: from every node `(q, g)` (index `q * (P + 1) + g`), the cost of the cheapest
    plan: for co-safe specs the cheapest path into a success state, else the cheapest lasso
    `prefix + c_e + omega * (c_e + back)` over accepting edges `e = x -> y` (prefix: to x;
    back: from y to x). inf where no plan exists.

    Args:
        spec: one (unstacked) compiled spec.
        goal_cost: float32[P + 1, P] (`cost_matrix`).
    """
    graph = edges(spec, goal_syms, empty_sym)
    num_states, num_props = graph.goal_next.shape
    width = num_props + 1
    dist = shortest_paths(_weights(graph, goal_cost))
    # accepting goal edges x = (q, g) -p-> y = (goal_next[q, p], p)
    x = (jnp.arange(num_states)[:, None, None] * width + jnp.arange(width)[None, :, None])
    x = jnp.broadcast_to(x, (num_states, width, num_props))
    y = jnp.broadcast_to(graph.goal_next[:, None, :] * width + jnp.arange(num_props)[None, None, :],
                         x.shape)
    c = jnp.where(graph.goal_acc[:, None, :] & _goal_mask(graph), goal_cost[None], jnp.inf)
    close = c * (1 + omega) + omega * dist[y, x]  # [S, G, P]
    # accepting empty-label edges x = (q, g) -> y = (empty_next[q], g)
    xe = jnp.arange(num_states)[:, None] * width + jnp.arange(width)[None, :]
    ye = graph.empty_next[:, None] * width + jnp.arange(width)[None, :]
    ce = jnp.where(graph.empty_acc[:, None], HOP, jnp.inf)
    close_e = ce * (1 + omega) + omega * dist[ye, xe]  # [S, G]
    # x is node xe = q * width + g whatever p: the cheapest closing per node, then the prefix
    # to it (adding a prefix keeps the order: the same minimum as over every edge)
    closing = jnp.minimum(jnp.min(close, axis=-1), close_e).reshape(-1)  # [N]
    success = jnp.repeat(spec.success & ~spec.violation, width)  # [N]
    # one reduction, no second [N, N] array: a co-safe plan ends on entering a success node
    end = jnp.where(spec.is_finite, jnp.where(success, 0.0, jnp.inf), closing)
    return jnp.min(dist + end[None], axis=1)


class Step(NamedTuple):
    """The first step of the chosen plan: `goal` int32[] the proposition to reach (-1: none, an
    empty-label or epsilon step comes first), `slot` int32[] the epsilon edge to take (-1:
    none), `cost` float32[] the plan's cost (inf: no plan)."""

    goal: jax.Array
    slot: jax.Array
    cost: jax.Array


def first_step(spec, q: jax.Array, last: jax.Array, first_cost: jax.Array, to_go: jax.Array,
               goal_syms: jax.Array, empty_sym: int) -> Step:
    """The cheapest out-edge of node `(q, last)` plus the cost to go from where it leads.

    Args:
        spec: one compiled spec; q: int32[] its state; last: int32[] the last goal (P: none).
        first_cost: float32[P], the cost of each goal from here (row P of `cost_matrix` built
            with the current critic values).
        to_go: float32[N], `cost_to_go`.
    """
    graph = edges(spec, goal_syms, empty_sym)
    width = graph.goal_next.shape[1] + 1
    p = jnp.arange(width - 1)
    ok = graph.goal_ok[q] & (graph.travel_ok[q] | (p == last))
    goal = jnp.where(ok, first_cost + to_go[graph.goal_next[q] * width + p], jnp.inf)
    empty = jnp.where(graph.empty_ok[q], HOP + to_go[graph.empty_next[q] * width + last], jnp.inf)
    eps = jnp.where(graph.eps_ok[q], HOP + to_go[graph.eps_next[q] * width + last], jnp.inf)
    best_goal, best_eps = jnp.argmin(goal), jnp.argmin(eps)
    options = jnp.stack([goal[best_goal], empty, eps[best_eps]])
    kind = jnp.argmin(options)
    found = jnp.isfinite(options[kind])
    return Step(
        goal=jnp.where(found & (kind == 0), best_goal, -1).astype(jnp.int32),
        slot=jnp.where(found & (kind == 2), best_eps, -1).astype(jnp.int32),
        cost=options[kind],
    )
