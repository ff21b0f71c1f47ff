"""PointLTL0MA2-v0 through the Gymnasium bridge: the checker, and the original's per-agent dict
observation and action layout."""

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax.gym  # noqa: F401  (registers the IDs with Gymnasium)

KEYS = ["accelerometer", "velocimeter", "gyro", "magnetometer", "green_zones_lidar",
        "yellow_zones_lidar", "blue_zones_lidar", "magenta_zones_lidar", "gremlins_lidar",
        "wall_sensor"]


def test_multi_agent_id_passes_the_gymnasium_checker_in_the_original_layout():
    env = gymnasium.make("PointLTL0MA2-v0")
    assert isinstance(env.unwrapped, specrl_jax.gym.GymMultiEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # the robot sensors are unbounded in the original's space too
        warnings.filterwarnings("ignore", message=".*(minimum|maximum) value is (-)?infinity")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=4)
    assert info == {"propositions": set()} and env.observation_space.contains(obs)
    assert list(obs) == ["agent_0", "agent_1"]
    assert list(obs["agent_1"]) == [f"{k}_1" for k in KEYS]
    assert sum(v.size for v in obs["agent_0"].values()) == 96
    # each agent sees the other one: a peak aliased into its two neighbouring bins
    assert 2 <= np.count_nonzero(obs["agent_0"]["gremlins_lidar_0"]) <= 3
    rng = np.random.default_rng(0)
    for _ in range(3):
        action = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in ("agent_0", "agent_1")}
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == 0.0 and not terminated and not truncated
        assert info["terminated"] == {"agent_0": False, "agent_1": False}
        assert info["propositions"] <= set(env.unwrapped.propositions)
    with pytest.raises(ValueError, match="agent_1"):
        env.step({"agent_0": np.zeros(2, np.float32)})
