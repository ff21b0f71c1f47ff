"""Infinite-horizon suites run at their own, longer horizon with bounded memory, count accepting
visits as a hand count does, and report the original automaton's count beside ours."""

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax import automata, specs
from specrl_jax.eval import random_policy
from specrl_jax.eval.evaluate import make_evaluator, record_episodes
from specrl_jax.eval.suites import evaluate_suites, originals, suite_horizon
from specrl_jax.tasks import TaskEnv


def test_suite_horizons_are_ten_finite_horizons_for_infinite_suites():
    assert suite_horizon("letter/finite/ind", 75) == 75
    assert suite_horizon("letter/infinite/rec", 75) == 750
    assert suite_horizon("zone/infinite/per", 1000) == 10_000
    assert suite_horizon("letter/infinite/rec", 75, horizon=120) == 120
    assert suite_horizon("letter/infinite/rec", 75, infinite_horizon=120) == 120
    assert suite_horizon("letter/finite/ind", 75, infinite_horizon=120) == 75


def test_accepting_visits_over_a_long_episode_match_a_hand_count():
    """`G F a`: every step on 'a' takes the accepting transition; over 750 steps of a random walk
    the evaluator's count equals the number of such steps in the recorded trajectory."""
    env, params = specrl_jax.make("LetterLTL0-v0", max_steps=750)
    spec = automata.compile_spec("G F a", env.propositions, alphabet=env.alphabet)
    task = TaskEnv(env, automata.stack([spec]))
    keys = jax.random.split(jax.random.key(3), 4)
    states, alive = jax.device_get(record_episodes(random_policy(env), task, params, keys,
                                                   jnp.zeros(4, jnp.int32)))
    on_a = states.propositions[:, 1:, 0] & alive[:, 1:]
    final = states.num_accepting[:, -1]
    np.testing.assert_array_equal(final, on_a.sum(axis=1))
    assert (alive.sum(axis=1) == 751).all() and (final > 5).all()  # the whole 750 steps ran


def test_evaluator_memory_does_not_grow_with_the_horizon():
    env, params = specrl_jax.make("LetterLTL0-v0")
    spec = automata.compile_spec("G F a & G F b", env.propositions, alphabet=env.alphabet)
    task = TaskEnv(env, automata.stack([spec]))
    sizes = []
    for horizon in (100, 10_000):
        evaluator = make_evaluator(random_policy(env), task, params.replace(max_steps=horizon),
                                   episodes_per_seed=8)
        compiled = evaluator.lower(None, jnp.asarray([1], jnp.uint32)).compile()
        memory = compiled.memory_analysis()
        sizes.append(memory.temp_size_in_bytes + memory.output_size_in_bytes)
    assert sizes[1] == sizes[0], sizes


def test_paper_infinite_suites_report_the_original_automatons_count_beside_ours():
    env, params = specrl_jax.make("LetterLTL0-v0")
    (rec,) = evaluate_suites(random_policy(env), "LetterLTL0-v0", env, params,
                             ["letter/infinite/rec"], episodes=4, seeds=[1], horizon=150,
                             log=lambda line: None)
    table = rec.result.table
    assert rec.result.horizon == 150 and table.num_accepting_original is not None
    assert table.num_accepting_original.shape == table.num_accepting.shape
    assert (table.num_accepting_original >= 0).all()  # every paper formula has its automaton
    metrics = rec.suite_metrics()
    assert "mu_acc_original_mean" in metrics
    assert len(specs.suite("letter/infinite/rec")) == table.success.shape[1]


def test_one_program_for_all_horizons_equals_one_evaluator_per_suite():
    """`evaluate_suites` runs a finite suite (75 steps) and an infinite one (40 steps here)
    through one compiled program whose specs and horizon are arguments: every table equals the
    one of a fixed-horizon evaluator of that suite alone."""
    env, params = specrl_jax.make("LetterLTL0-v0")
    policy = random_policy(env)
    names = ["letter/finite/ind", "letter/infinite/rec"]
    results = evaluate_suites(policy, "LetterLTL0-v0", env, params, names, episodes=3,
                              seeds=[1, 2], infinite_horizon=40, log=lambda line: None)
    for name, result, steps in zip(names, results, (75, 40)):
        spec_stack = automata.compile_suite(specs.suite(name), env.propositions, env.alphabet)
        alone = make_evaluator(policy, TaskEnv(env, spec_stack), params.replace(max_steps=steps),
                               episodes_per_seed=3, original=originals(specs.suite(name), env))(
            None, jnp.asarray([1, 2], jnp.uint32))
        assert result.result.horizon == steps
        for field in ("success", "violation", "steps", "num_accepting", "num_accepting_original"):
            expected = getattr(alone, field)
            np.testing.assert_array_equal(getattr(result.result.table, field),
                                          None if expected is None else np.asarray(expected),
                                          err_msg=field)
