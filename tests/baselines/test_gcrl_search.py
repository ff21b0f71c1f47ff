"""GCRL-LTL's value-weighted subgoal search against a brute-force enumeration of plans.

The brute force builds the path graph from the automaton tables with plain Python loops and
enumerates every simple prefix and every simple loop (a goal edge to another proposition only
where the empty label is safe; self-loops only accepting ones, or in states with an epsilon
edge): co-safe specs, the cheapest path into a
success state; others, `prefix + c + OMEGA * (c + back)` over the accepting edges `x -c-> y`.
The search must find the same cost from every start state and the same first step.
"""

import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax import automata
from specrl_jax.baselines.gcrl import search

PROPS = ("a", "b", "c")
FORMULAS = ["!a U (b & F c)", "F (a & F (b & F c))",
            "G F a & G !c", "F G a", "G F (a | b) & G (c -> F a)"]


def _edges(spec, costs):
    """Path-graph edges as Python tuples: (source, target, cost, accepting, goal, slot)."""
    delta, acc = np.asarray(spec.delta), np.asarray(spec.accepting)
    eps, dead = np.asarray(spec.epsilon), np.asarray(spec.violation)
    alphabet = np.asarray(spec.alphabet)
    num_props = alphabet.shape[1]
    rows = {p: int(np.nonzero((alphabet == np.eye(num_props, dtype=bool)[p]).all(1))[0][0])
            for p in range(num_props)}
    empty = int(np.nonzero(~alphabet.any(1))[0][0])
    out = {}
    for q in range(delta.shape[0]):
        for g in range(num_props + 1):
            edges = out.setdefault((q, g), [])
            if dead[q]:
                continue
            jumps = (eps[q] >= 0).any()
            for p, row in rows.items():
                t = int(delta[q, row])
                travel = not dead[delta[q, empty]] or g == p  # crossing empty cells is safe
                loop_ok = t != q or acc[q, row] or jumps  # no idle self-loop goals
                if not dead[t] and travel and loop_ok:
                    edges.append(((t, p), float(costs[g, p]), bool(acc[q, row]), p, -1))
            t = int(delta[q, empty])
            if not dead[t] and (t != q or acc[q, empty]):
                edges.append(((t, g), search.HOP, bool(acc[q, empty]), -1, -1))
            for slot, t in enumerate(eps[q]):
                if t >= 0 and not dead[t]:
                    edges.append(((int(t), g), search.HOP, False, -1, slot))
    return out


def _simple_paths(out, start):
    """Every simple path from `start`: yields (end node, cost, first edge or None)."""
    stack = [(start, 0.0, None, {start})]
    while stack:
        node, cost, first, seen = stack.pop()
        yield node, cost, first
        for target, c, acc, goal, slot in out[node]:
            if target not in seen:
                stack.append((target, cost + c, first or (goal, slot), seen | {target}))


def _brute_force(spec, costs, start):
    """(cheapest plan cost, its first (goal, slot)) from node `start` by enumeration."""
    out = _edges(spec, costs)
    best, best_first = np.inf, None
    finite = bool(spec.is_finite)
    success, dead = np.asarray(spec.success), np.asarray(spec.violation)
    back = {}
    for x, prefix, first in _simple_paths(out, start):
        if finite:
            if success[x[0]] and not dead[x[0]] and prefix < best:
                best, best_first = prefix, first
            continue
        for y, c, acc, goal, slot in out[x]:
            if not acc:
                continue
            if y not in back:
                back[y] = {}
                for z, cost, _ in _simple_paths(out, y):
                    back[y][z] = min(back[y].get(z, np.inf), cost)
            total = prefix + c + search.OMEGA * (c + back[y].get(x, np.inf))
            if total < best:
                best, best_first = total, first or (goal, slot)
    return best, best_first


@pytest.mark.parametrize("formula", FORMULAS)
def test_search_matches_brute_force_enumeration(formula):
    alphabet = automata.zero_or_one(len(PROPS))
    spec = automata.compile_spec(formula, PROPS, alphabet=alphabet)
    rows, empty = search.goal_symbols(alphabet)
    rng = np.random.default_rng(zlib.crc32(formula.encode()))
    start_values = rng.uniform(-0.1, 1.1, len(PROPS)).astype(np.float32)
    pair_values = rng.uniform(-0.1, 1.1, (len(PROPS), len(PROPS))).astype(np.float32)
    costs = search.cost_matrix(jnp.asarray(start_values), jnp.asarray(pair_values))
    to_go = np.asarray(jax.jit(search.cost_to_go, static_argnums=3)(spec, costs, jnp.asarray(rows),
                                                                     empty))
    width = len(PROPS) + 1
    first = jax.jit(search.first_step, static_argnums=6)
    num_states = spec.delta.shape[0]
    checked = 0
    for q in range(num_states):
        if bool(spec.violation[q]) or (bool(spec.is_finite) and bool(spec.success[q])):
            continue
        for g in range(width):
            want, want_first = _brute_force(spec, np.asarray(costs), (q, g))
            got = to_go[q * width + g]
            same = np.isclose(got, want, rtol=1e-5, atol=1e-5)
            assert same or (np.isinf(got) and np.isinf(want)), (formula, q, g, got, want)
            step = first(spec, jnp.int32(q), jnp.int32(g), costs[len(PROPS)], jnp.asarray(to_go),
                         jnp.asarray(rows), empty)
            if g == len(PROPS) and np.isfinite(want):  # a fresh node: the first edge costs row P
                assert np.isclose(float(step.cost), want, rtol=1e-5, atol=1e-5)
                assert (int(step.goal), int(step.slot)) == want_first, (formula, q, step)
                checked += 1
    assert checked >= 1


def test_cost_matrix_reads_values_as_one_minus_v_clipped_with_free_stays():
    pair = jnp.array([[0.9, 0.6], [0.1, 0.3]])
    costs = np.asarray(search.cost_matrix(jnp.array([0.25, 1.5]), pair))
    hop = search.HOP
    np.testing.assert_allclose(costs, [[hop, 0.4 + hop], [0.9 + hop, hop], [0.75 + hop, hop]],
                               rtol=1e-6)


def test_as_coded_costs_read_only_single_goal_values_through_min():
    """The original's `compute_cost`: `min(1 - V(s0, p), 0)` for every edge into p whatever the
    previous goal (0 unless V > 1), plus HOP, never below 0."""
    pair = jnp.array([[0.9, 0.6], [0.1, 0.3]])
    costs = np.asarray(search.cost_matrix(jnp.array([0.25, 1.0005]), pair, as_coded=True))
    hop = search.HOP
    np.testing.assert_allclose(costs, [[hop, hop - 5e-4]] * 3, rtol=1e-4)
    assert (np.asarray(search.cost_matrix(jnp.array([3.0, 0.5]), pair, as_coded=True)) >= 0).all()


def test_unreachable_acceptance_gives_no_plan():
    alphabet = automata.zero_or_one(2)
    spec = automata.compile_spec("F a", ("a", "b"), alphabet=alphabet)
    rows, empty = search.goal_symbols(alphabet)
    rows = np.array([-1, rows[1]], np.int32)  # 'a' can never be produced alone
    costs = search.cost_matrix(jnp.array([0.5, 0.5]), jnp.full((2, 2), 0.5))
    to_go = jax.jit(search.cost_to_go, static_argnums=3)(spec, costs, jnp.asarray(rows), empty)
    step = jax.jit(search.first_step, static_argnums=6)(spec, spec.init, jnp.int32(2), costs[2],
                                                        to_go, jnp.asarray(rows), empty)
    assert np.isinf(float(step.cost)) and int(step.goal) == -1 and int(step.slot) == -1


def test_persistence_jumps_only_while_standing_on_the_proposition():
    """F G a: after the epsilon jump the empty label is a violation, so the plan reaches 'a'
    first and jumps only from it (jumping at once would be as cheap in a graph that ignored the
    empty cells crossed on the way)."""
    alphabet = automata.zero_or_one(len(PROPS))
    spec = automata.compile_spec("F G a", PROPS, alphabet=alphabet)
    rows, empty = (jnp.asarray(x) if i == 0 else x for i, x in
                   enumerate(search.goal_symbols(alphabet)))
    costs = search.cost_matrix(jnp.array([0.5, 0.9, 0.9]), jnp.full((3, 3), 0.5))
    to_go = jax.jit(search.cost_to_go, static_argnums=3)(spec, costs, rows, empty)
    first = jax.jit(search.first_step, static_argnums=6)
    fresh = first(spec, spec.init, jnp.int32(3), costs[3], to_go, rows, empty)
    assert (int(fresh.goal), int(fresh.slot)) == (0, -1)
    on_a = first(spec, spec.init, jnp.int32(0), costs[3], to_go, rows, empty)
    assert (int(on_a.goal), int(on_a.slot)) == (-1, 0)


def test_cost_to_go_holds_about_the_distance_matrix_per_search():
    """The evaluator runs one search per episode side by side: each may hold a few N x N
    arrays, not one row of N per accepting goal edge (P times more, ~14 N x N here)."""
    props = tuple("abcdefghijkl")
    alphabet = automata.zero_or_one(len(props))
    spec = automata.compile_spec("G F a & G F b & G (c -> F d) & G !e", props, alphabet=alphabet)
    rows, empty = search.goal_symbols(alphabet)
    batch, nodes = 8, spec.delta.shape[0] * (len(props) + 1)
    costs = jnp.full((batch, len(props) + 1, len(props)), 0.5)
    searches = jax.jit(jax.vmap(lambda c: search.cost_to_go(spec, c, jnp.asarray(rows), empty)))
    temp = searches.lower(costs).compile().memory_analysis().temp_size_in_bytes
    assert temp < batch * 5 * nodes * nodes * 4
