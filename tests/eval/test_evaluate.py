"""`evaluate`: episode outcomes, determinism, stateful policies and epsilon actions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from eval.tiny_world import (
    TinyParams,
    TinyWorld,
    persistence_spec,
    reach_avoid_spec,
    recurrence_spec,
    stack_specs,
)

from specrl_jax.eval.evaluate import evaluate, make_evaluator, record_episodes
from specrl_jax.tasks import TaskEnv
from specrl_jax.tasks.policy import StatefulPolicy, random_policy, split_action

ENV = TinyWorld()
PARAMS = TinyParams(max_steps=12)
SPECS = stack_specs([reach_avoid_spec(), recurrence_spec(), persistence_spec()])
RIGHT, DOWN = 3, 1


@pytest.fixture(scope="module")
def random_result():
    return evaluate(random_policy(ENV), (ENV, PARAMS), SPECS, seeds=[1, 2, 3], episodes_per_seed=16)


def test_table_shapes_and_outcome_invariants(random_result):
    t = random_result.table
    assert t.success.shape == (3, 3, 16)
    assert not (t.success & t.violation).any()
    assert ((t.steps >= 1) & (t.steps <= PARAMS.max_steps)).all()
    # finite spec: an episode that neither succeeds nor violates runs to the horizon
    timeout = ~t.success[:, 0] & ~t.violation[:, 0]
    assert (t.steps[:, 0][timeout] == PARAMS.max_steps).all()
    assert t.success[:, 0].any() and t.violation[:, 0].any()  # random play does both
    # infinite specs never succeed; non-violating episodes run to the horizon
    assert not t.success[:, 1:].any()
    assert (t.steps[:, 1:][~t.violation[:, 1:]] == PARAMS.max_steps).all()
    assert t.num_accepting[:, 1].max() >= 1
    assert random_result.is_finite.tolist() == [True, False, False]


def test_horizon_is_the_episode_length_beyond_the_worlds_time_limit():
    """An infinite-horizon run longer than the world's `max_steps` (Zone: 10,000 against
    1,000) lasts the horizon: the world does not end the episodes at its own limit."""
    long = evaluate(random_policy(ENV), (ENV, PARAMS), SPECS, seeds=[1], episodes_per_seed=16,
                    horizon=3 * PARAMS.max_steps)
    t = long.table
    alive = ~t.violation[:, 1:]
    assert alive.any()
    assert (t.steps[:, 1:][alive] == 3 * PARAMS.max_steps).all()
    finite_timeout = ~t.success[:, 0] & ~t.violation[:, 0]
    assert (t.steps[:, 0][finite_timeout] == 3 * PARAMS.max_steps).all()


def test_deterministic_and_independent_of_the_other_seeds_and_specs(random_result):
    again = evaluate(random_policy(ENV), (ENV, PARAMS), SPECS, seeds=[1, 2, 3], episodes_per_seed=16)
    for full, repeat in zip(random_result.table, again.table):
        np.testing.assert_array_equal(full, repeat)
    # seed 2 alone, the last two specs in another order: the same episodes
    alone = evaluate(random_policy(ENV), (ENV, PARAMS), stack_specs([persistence_spec(),
                     recurrence_spec()]), seeds=[2], episodes_per_seed=16)
    for full, single in zip(random_result.table, alone.table):
        if full is not None:  # untracked fields (no original automaton) stay None
            np.testing.assert_array_equal(full[1, 1:], single[0, ::-1])
    assert not np.array_equal(random_result.table.steps[0], random_result.table.steps[1])


def test_evaluate_agrees_with_recorded_episodes():
    task = TaskEnv(ENV, SPECS)
    keys = jax.random.split(jax.random.key(4), 6)
    index = jnp.arange(6) % 3
    states, alive = record_episodes(random_policy(ENV), task, PARAMS, keys, index)
    final = jax.tree.map(lambda x: x[:, -1], states)
    assert (np.asarray(states.time[:, 0]) == 0).all()
    np.testing.assert_array_equal(np.asarray(alive.sum(axis=1)) - 1, np.asarray(final.time))
    # once an episode ends, its state stays frozen
    for i in range(6):
        n = int(alive[i].sum())
        np.testing.assert_array_equal(np.asarray(states.time[i, n - 1:]), n - 1)
    # a capture keeps only its part of each state, the same values
    kept, kept_alive = record_episodes(random_policy(ENV), task, PARAMS, keys, index,
                                       capture=lambda s: (s.time, s.num_accepting))
    np.testing.assert_array_equal(np.asarray(kept_alive), np.asarray(alive))
    np.testing.assert_array_equal(np.asarray(kept[0]), np.asarray(states.time))
    np.testing.assert_array_equal(np.asarray(kept[1]), np.asarray(states.num_accepting))


def test_stateful_policy_carry_restarts_every_episode():
    def by_time(params, obs, task_state, key):
        return jnp.where(task_state.time < 2, RIGHT, DOWN)

    counter = StatefulPolicy(
        init=lambda params, obs, task_state, key: jnp.zeros((), jnp.int32),
        apply=lambda params, obs, task_state, count, key: (
            jnp.where(count < 2, RIGHT, DOWN), count + 1),
    )
    pure = evaluate(by_time, (ENV, PARAMS), SPECS, seeds=[5], episodes_per_seed=8)
    stateful = evaluate(counter, (ENV, PARAMS), SPECS, seeds=[5], episodes_per_seed=8)
    for a, b in zip(pure.table, stateful.table):
        np.testing.assert_array_equal(a, b)


def test_per_seed_parameters_in_one_call_equal_one_call_per_seed():
    """One trained run per seed: entry i of the parameters serves seed i, side by side or in
    sequence, exactly as evaluating each seed alone with its own parameters."""
    def move(params, obs, task_state, key):
        return jnp.where(task_state.time < params, RIGHT, DOWN)

    per_seed = jnp.asarray([0, 3], jnp.int32)
    seeds = jnp.asarray([4, 9], jnp.uint32)
    task = TaskEnv(ENV, SPECS)
    for sequential in (False, True):
        evaluator = make_evaluator(move, task, PARAMS, 8, sequential_seeds=sequential,
                                   params_per_seed=True)
        together = evaluator(per_seed, seeds)
        for i in range(2):
            alone = make_evaluator(move, task, PARAMS, 8)(per_seed[i], seeds[i:i + 1])
            np.testing.assert_array_equal(together.steps[i], alone.steps[0])
            np.testing.assert_array_equal(together.success[i], alone.success[0])
    assert not np.array_equal(together.steps[0], together.steps[1])


def test_epsilon_actions_from_the_policy():
    def epsilon_first(params, obs, task_state, key):
        return jnp.int32(DOWN), task_state.time == 0

    result = evaluate(epsilon_first, (ENV, PARAMS), stack_specs([persistence_spec()]),
                      seeds=[1], episodes_per_seed=16)
    # step 1 is the epsilon step; step 2 moves down from (0, 0): off `a` the jumped run dies, a
    # wrong guess that falls back to the waiting state (`tasks.sources.fall_back_run`), since
    # no word violates `FG a`; on `a` every step accepts until the agent leaves it
    t = result.table
    assert not t.violation.any() and (t.steps >= 2).all()
    assert (t.num_accepting <= t.steps - 2).all()
    assert (t.num_accepting == 0).mean() > 0.5 and (t.num_accepting > 0).any()


def test_bad_arguments():
    with pytest.raises(ValueError, match="seeds"):
        evaluate(random_policy(ENV), (ENV, PARAMS), SPECS, seeds=[], episodes_per_seed=1)
    with pytest.raises(ValueError, match="episodes_per_seed"):
        evaluate(random_policy(ENV), (ENV, PARAMS), SPECS, seeds=[1], episodes_per_seed=0)
    with pytest.raises(TypeError, match="policy"):
        evaluate("oracle", (ENV, PARAMS), SPECS, seeds=[1], episodes_per_seed=1)
    with pytest.raises(TypeError, match="suite"):
        evaluate(random_policy(ENV), (ENV, PARAMS), "letter/finite/ind", seeds=[1],
                 episodes_per_seed=1)


def test_split_action_turns_epsilon_flags_into_slots():
    for flag, slot in ((True, 0), (False, -1), (jnp.int32(1), 1), (jnp.int32(-1), -1)):
        _, take = split_action((jnp.int32(2), flag))
        assert take.dtype == jnp.int32 and int(take) == slot
    action, take = split_action(jnp.int32(3))
    assert int(action) == 3 and int(take) == -1
