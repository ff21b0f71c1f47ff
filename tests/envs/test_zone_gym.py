"""Zone IDs through the Gymnasium bridge: the checker and the original flat layout, for each
robot (the Ant's reset and step compile in ~1 min on a 2-core CPU)."""

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax.gym  # noqa: F401  (registers the IDs with Gymnasium)


@pytest.mark.parametrize(
    "env_id, size, action_dim",
    [("PointLTL2-v0.partial_overlap", 80, 2), ("CarLTL0-v0", 92, 2), ("AntLTL0-v0", 108, 8)],
)
def test_zone_ids_pass_the_gymnasium_checker(env_id, size, action_dim):
    env = gymnasium.make(env_id)
    assert env.observation_space.shape == (size,) and env.action_space.shape == (action_dim,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # the robot sensors are unbounded in the original's space too
        warnings.filterwarnings("ignore", message=".*(minimum|maximum) value is (-)?infinity")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=3)
    assert info == {"propositions": set()} and env.observation_space.contains(obs)
    wall = obs[-4:]  # wall_sensor last, exp(-distance) to walls 3.3 m away at most +-2.1 m off
    assert ((wall > np.exp(-6.6)) & (wall < np.exp(-1.1))).all()
    for action in np.random.default_rng(0).uniform(-1, 1, (5, action_dim)).astype(np.float32):
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == 0.0 and not terminated and not truncated
        assert info["propositions"] <= {"blue", "green", "magenta", "yellow"}
