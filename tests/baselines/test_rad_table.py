"""RAD's embedding table: the breadth-first search finds exactly the reachable state tuples, the
table's rows equal the frozen encoder's per-step embeddings (every reachable tuple, the tuples
a task loop visits, the evaluated specs' DFA states), and a bank over the row budget is embedded
per step with a warning."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax import automata
from specrl_jax.automata import rad_sampler
from specrl_jax.baselines import rad
from specrl_jax.baselines.rad import table as rad_table
from specrl_jax.baselines.rad.encoder import RADEncoder, build_graphs, graph_of
from specrl_jax.envs.letter import LetterConfig, make_letter_world

TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def small():
    """A 5x5 LetterWorld of 4 letters, a bank of 24 RAD conjunctions over its alphabet, and a
    small random frozen encoder (2 rounds)."""
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=tuple("abcd"), counts=1),
                                      max_steps=12)
    params = world.with_map_bank(jax.random.key(0), params, num_maps=32)
    bank = rad_sampler.sample_bank(24, np.asarray(world.alphabet), seed=3, max_size=40)
    graphs = build_graphs(bank)
    graph = graph_of(graphs, bank, 0, np.zeros(bank.max_conjuncts, np.int32))
    encoder_params = RADEncoder(hidden=16, num_layers=2).init(jax.random.key(1), graph)
    return world, params, bank, graphs, encoder_params


def reachable_by_search(bank) -> set[tuple[int, tuple[int, ...]]]:
    """(index, q) of every reachable tuple: a plain breadth-first search over Python tuples."""
    delta = np.asarray(bank.delta)
    found = set()
    for k in range(bank.size):
        start = (0,) * bank.max_conjuncts
        seen, queue = {start}, [start]
        for q in queue:
            for a in range(delta.shape[-1]):
                nxt = tuple(int(delta[k, n, s, a]) for n, s in enumerate(q))
                if nxt not in seen:
                    seen.add(nxt)
                    queue.append(nxt)
        found |= {(k, q) for q in seen}
    return found


def test_reachable_positions_are_the_reachable_tuples_and_positions_round_trip(small):
    _, _, bank, _, _ = small
    seen = rad_table.reachable_positions(bank)
    at = np.flatnonzero(seen)
    index, q = rad_table.tuples_at(np.asarray(bank.num_states), at)
    assert {(int(k), tuple(int(s) for s in t)) for k, t in zip(index, q)} == reachable_by_search(bank)
    place, base, _ = rad_table.product_space(np.asarray(bank.num_states))
    np.testing.assert_array_equal(rad_table.positions(place, base, index, q), at)
    # several conjuncts advanced at once, and tuples of more than one conjunction
    assert (np.count_nonzero(q, axis=1) >= 2).any() and len(set(index.tolist())) == bank.size
    assert seen.sum() < seen.size  # the product space holds unreachable tuples too


def test_table_rows_equal_the_per_step_embeddings_of_every_reachable_tuple(small):
    _, _, bank, graphs, encoder_params = small
    embed = rad.embedder(encoder_params, graphs, bank, num_layers=2)
    tabulated = rad.bank_embedder(encoder_params, graphs, bank, num_layers=2)
    at = np.flatnonzero(rad_table.reachable_positions(bank))
    at = np.random.default_rng(0).permutation(at)  # a batch of tuples in no particular order
    index, q = rad_table.tuples_at(np.asarray(bank.num_states), at)
    expected = jax.jit(jax.vmap(embed))(index, q)
    got = jax.jit(jax.vmap(tabulated))(index, q)
    np.testing.assert_allclose(got, expected, atol=TOLERANCE, rtol=0)
    assert len(at) > 100 and float(jnp.std(expected, axis=0).mean()) > 1e-3  # and they differ


def rollout_embeddings(method, key, num_envs: int = 32, num_steps: int = 40):
    """The task index int32[T, B], states int32[T, B, N] and embedding float32[T, B, E] of every
    observation of a random-action rollout."""
    env = method.env
    key_reset, key_run = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key_reset, num_envs),
                                                        None)

    def step(carry, key_step):
        obs, state = carry
        key_action, key_env = jax.random.split(key_step)
        action = jax.random.randint(key_action, (num_envs,), 0, 4)
        obs, state, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
            jax.random.split(key_env, num_envs), state, action, None)
        return (obs, state), (state.task.index, state.task.q, obs.embedding)

    return jax.lax.scan(step, (obs, state), jax.random.split(key_run, num_steps))[1]


def test_task_loop_embeddings_equal_with_and_without_the_table(small):
    world, params, bank, _, encoder_params = small
    per_step, table = (rad.make_method(world, params, bank=bank, encoder_params=encoder_params,
                                       encoder_layers=2, max_table_rows=rows)
                       for rows in (0, rad_table.MAX_TABLE_ROWS))
    key = jax.random.key(4)
    index, q, expected = jax.jit(functools.partial(rollout_embeddings, per_step))(key)
    index_t, q_t, got = jax.jit(functools.partial(rollout_embeddings, table))(key)
    np.testing.assert_array_equal(index_t, index)
    np.testing.assert_array_equal(q_t, q)
    np.testing.assert_allclose(got, expected, atol=TOLERANCE, rtol=0)
    advanced = np.any(q != 0, axis=-1)
    assert advanced.mean() > 0.2 and len(np.unique(index)) > 10, (advanced.mean(), index)


def test_a_bank_over_the_row_budget_raises_or_falls_back_to_per_step(small):
    world, params, bank, graphs, encoder_params = small
    rows = int(rad_table.reachable_positions(bank).sum())
    encode = jax.vmap(rad.embedder(encoder_params, graphs, bank, num_layers=2))
    assert rad_table.build_table(bank, encode, max_rows=rows).num_rows == rows
    with pytest.raises(ValueError, match=f"reach {rows:,} state tuples.*max_rows={rows - 1}"):
        rad_table.build_table(bank, encode, max_rows=rows - 1)
    with pytest.raises(ValueError, match="state tuples, over the table's budget of 32 "):
        rad_table.build_table(bank, encode, max_rows=1)
    with pytest.warns(UserWarning, match="running the encoder every step instead"):
        method = rad.make_method(world, params, bank=bank, encoder_params=encoder_params,
                                 encoder_layers=2, max_table_rows=rows - 1)
    embed = rad.embedder(encoder_params, graphs, bank, num_layers=2)
    rollout = functools.partial(rollout_embeddings, method, num_envs=8, num_steps=10)
    index, q, got = jax.jit(rollout)(jax.random.key(5))
    expected = jax.vmap(jax.vmap(embed))(index, q)
    np.testing.assert_allclose(got, expected, atol=TOLERANCE, rtol=0)


def test_evaluation_table_equals_the_per_step_embeddings_of_every_spec_state(small):
    world, _, _, _, encoder_params = small
    formulas = ["F a", "!a U b", "F (a & F (b & F c))", "(!d U a) & F b", "!c U (a & F d)"]
    compiled = automata.compile_suite(formulas, world.propositions, world.alphabet)
    bank, _ = rad_sampler.bank_of_specs(compiled)
    graphs = build_graphs(bank)
    num_states = np.asarray(bank.num_states)[:, 0]
    index = np.repeat(np.arange(bank.size), num_states).astype(np.int32)
    q = np.concatenate([np.arange(s) for s in num_states]).astype(np.int32)[:, None]
    embed = rad.embedder(encoder_params, graphs, bank, num_layers=2)
    tabulated = rad.bank_embedder(encoder_params, graphs, bank, num_layers=2)
    expected = jax.vmap(embed)(index, q)
    np.testing.assert_allclose(jax.vmap(tabulated)(index, q), expected, atol=TOLERANCE, rtol=0)
    assert num_states.max() >= 4 and len(q) == int(rad_table.reachable_positions(bank).sum())
