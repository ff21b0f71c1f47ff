"""`batch(env, B)` over every multi-agent world, stepped under `jit` and in checked mode: the
flags are per agent (`bool[B, N]`), a world's episode ends for all its agents together
(`env.episode_done`), and invalid actions are flagged per world as in single-agent worlds."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax.envs import batch, checked
from specrl_jax.envs.registry import list_envs

MA_IDS = [env_id for env_id in list_envs() if "MA" in env_id]
NUM_WORLDS = 3


def test_every_multi_agent_id_is_covered():
    assert MA_IDS == ["PointLTL0MA2-v0", "PointLTL0MA3-v0"]


@pytest.mark.parametrize("env_id", MA_IDS)
def test_batch_steps_under_jit_and_ends_episodes_per_world(env_id):
    env, params = specrl_jax.make(env_id, max_steps=2)
    num_agents, action_dim = env.action_space.shape
    key = jax.random.key(1)
    actions = jnp.zeros((NUM_WORLDS, num_agents, action_dim))
    if env_id == MA_IDS[0]:
        # the default (resets_per_step 1 < 3: finished worlds' resets scattered) traces: it used
        # to fail at `nonzero(done)` on the per-agent flags (traced only: compiling is slow)
        default = batch(env, NUM_WORLDS)
        state = jax.eval_shape(default.reset, key, params)[1]
        shapes = jax.eval_shape(default.step, key, state, actions, params)
        assert shapes[3].shape == (NUM_WORLDS, num_agents)
        assert shapes[5]["episode_done"].shape == (NUM_WORLDS,)
    # compiled (one reset per world and step, a single branch: cheaper to compile)
    worlds = batch(env, NUM_WORLDS, resets_per_step=NUM_WORLDS)
    _, state = checked(worlds).reset(jax.random.key(0), params)  # jit(worlds.reset)
    step = jax.jit(worlds.step)
    # world 0 valid (2.0 is out of the box: clipped, valid), world 1 NaN, world 2 inf
    actions = actions.at[0, 0, 0].set(2.0).at[1, 0, 0].set(jnp.nan)
    actions = actions.at[2, num_agents - 1, 1].set(jnp.inf)
    obs, after, _, terminated, truncated, info = step(key, state, actions, params)
    assert terminated.shape == truncated.shape == (NUM_WORLDS, num_agents)
    assert info["invalid_action"].tolist() == [False, True, True]
    # an invalid action ends its world's episode for every agent, and the world restarts
    assert terminated.tolist() == [[False] * num_agents] + [[True] * num_agents] * 2
    assert info["episode_done"].tolist() == [False, True, True]
    assert after.time.tolist() == [1, 0, 0] and not np.asarray(after.terminated).any()
    np.testing.assert_array_equal(info["final_observation"]["ego"][0], obs["ego"][0])
    assert not np.allclose(info["final_observation"]["ap"][1:], obs["ap"][1:])
    for leaf in jax.tree.leaves((obs, after)):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert np.isfinite(np.asarray(leaf)).all()
    if env_id == MA_IDS[0]:  # checked mode: the same compiled step (persistent cache), raising
        with pytest.raises(ValueError, match=r"invalid actions in 2 of 3 worlds \(indices \[1, 2\]\)"):
            checked(worlds).step(key, state, actions, params)
    # next step: world 0 reaches the horizon (all agents truncated) and restarts alone
    obs, after, _, terminated, truncated, info = step(
        jax.random.key(2), after, jnp.zeros_like(actions), params
    )
    assert truncated.tolist() == [[True] * num_agents] + [[False] * num_agents] * 2
    assert not np.asarray(terminated).any() and not info["invalid_action"].any()
    assert info["episode_done"].tolist() == [True, False, False]
    assert after.time.tolist() == [0, 1, 1]
