"""Zone IDs through the Gymnasium bridge: the checker and the original flat layout.

Point and Car only: the Ant's MJX step alone takes minutes to compile on CPU."""

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax.gym  # noqa: F401  (registers the IDs with Gymnasium)


@pytest.mark.parametrize("env_id, size", [("PointLTL2-v0.partial_overlap", 80), ("CarLTL0-v0", 92)])
def test_zone_ids_pass_the_gymnasium_checker(env_id, size):
    env = gymnasium.make(env_id)
    assert env.observation_space.shape == (size,) and env.action_space.shape == (2,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # the robot sensors are unbounded in the original's space too
        warnings.filterwarnings("ignore", message=".*(minimum|maximum) value is (-)?infinity")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=3)
    assert info == {"propositions": set()} and env.observation_space.contains(obs)
    wall = obs[-4:]  # wall_sensor last, exp(-distance) to walls 3.3 m away at most +-2.1 m off
    assert ((wall > np.exp(-6.6)) & (wall < np.exp(-1.1))).all()
    for action in np.random.default_rng(0).uniform(-1, 1, (5, 2)).astype(np.float32):
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == 0.0 and not terminated and not truncated
        assert info["propositions"] <= {"blue", "green", "magenta", "yellow"}
