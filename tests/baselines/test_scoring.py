"""Candidate scoring a chunk at a time (`baselines.scoring`), GenZ-LTL's distinct candidates, and
the memory the planners' evaluators hold per episode."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax import automata, specs
from specrl_jax.baselines import deepltl, genz
from specrl_jax.baselines.scoring import score_chosen
from specrl_jax.eval.evaluate import make_evaluator
from specrl_jax.tasks import TaskEnv


def test_score_chosen_scores_the_chosen_only_whatever_their_count():
    score = lambda ids: 10.0 * ids.astype(jnp.float32) + 1.0  # noqa: E731
    chosen = np.zeros((5, 10), bool)
    chosen[1, [3]] = True
    chosen[2, [0, 4, 5, 9]] = True  # one full chunk
    chosen[3, [1, 2, 3, 6, 8]] = True  # a chunk and one more
    chosen[4] = True
    scores = jax.jit(jax.vmap(lambda c: score_chosen(score, c, chunk=4)))
    got = np.asarray(scores(jnp.asarray(chosen)))
    want = np.where(chosen, 10.0 * np.arange(10) + 1.0, -np.inf)
    np.testing.assert_array_equal(got, want)


def test_first_of_kind_keeps_the_first_of_equal_letter_and_avoid_set():
    avoid = np.array([[0, 0, 1], [0, 0, 1], [1, 0, 0], [0, 0, 1]], bool)  # sequences 0, 1, 3 alike
    allowed = np.array([[1, 0, 0], [1, 1, 0], [1, 1, 0], [0, 1, 0]], bool)  # [C, P]
    got = np.asarray(genz.first_of_kind(jnp.asarray(avoid), jnp.asarray(allowed.reshape(-1))))
    want = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 0]], bool)
    np.testing.assert_array_equal(got.reshape(4, 3), want)


def _temp_per_episode(module, episodes: int, num_specs: int = 8) -> float:
    """Temporary bytes per (spec, episode) of the compiled evaluator of `module`'s test-time
    policy on LetterWorld's first response spec (27 states, 36 candidate sequences, 432 GenZ-LTL
    candidates), random weights, one seed. The spec is repeated `num_specs` times: the specs
    share each episode's reset (layout), which would otherwise outweigh the policy."""
    env, params = specrl_jax.make("LetterLTL0-v0")
    formula = specs.suite("letter/infinite/rsp")[0]
    spec = automata.compile_spec(formula, env.propositions, alphabet=env.alphabet)
    task = TaskEnv(env, automata.stack([spec] * num_specs))
    method = module.make_method(env, params, "letter")
    obs, _ = jax.eval_shape(method.env.reset, jax.random.key(0), method.init_task_params())
    net_params = method.network.init(
        jax.random.key(1), jax.tree.map(lambda x: jnp.zeros((1, *x.shape), x.dtype), obs))
    policy = module.make_policy(method.network, env.alphabet, env.obs_kinds)
    evaluator = make_evaluator(policy, task, params.replace(max_steps=4),
                               episodes_per_seed=episodes)
    compiled = evaluator.lower(net_params, jnp.asarray([1], jnp.uint32)).compile()
    return compiled.memory_analysis().temp_size_in_bytes / (episodes * num_specs)


@pytest.mark.parametrize("module", [genz, deepltl], ids=["genz", "deepltl"])
def test_planner_memory_per_episode_is_a_chunk_of_candidates(module):
    # Scoring every candidate at once (under vmap, at every step, with the weights copied per
    # episode) held ~7.6 MiB (GenZ-LTL) and ~1.1 MiB (DeepLTL) per episode here; a chunk ~80 KiB.
    assert _temp_per_episode(module, 32) < 2**18


def test_score_chosen_scores_a_lone_candidate_known_at_compile_time():
    # A chosen mask that XLA constant-folds (a spec known at trace time): with the loop stepping
    # by `chunk`, jaxlib 0.10.2 ran `0 < 1` zero times on the CPU and returned only -inf, so
    # GenZ-LTL's argmax fell on candidate 0 (proposition 0, possibly an avoided one).
    score = lambda ids: ids.astype(jnp.float32) - 5.0  # noqa: E731
    for count in range(1, 6):
        chosen = np.zeros(8, bool)
        chosen[8 - count:] = True
        got = np.asarray(jax.jit(lambda: score_chosen(score, jnp.asarray(chosen), chunk=4))())
        np.testing.assert_array_equal(got, np.where(chosen, np.arange(8) - 5.0, -np.inf))
