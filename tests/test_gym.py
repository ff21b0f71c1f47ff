"""The Gymnasium bridge: registration, the checker, original layout, seeding, the vector env."""

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax
import specrl_jax.gym
from specrl_jax.gym import GymEnv, GymVectorEnv

LETTERS = "abcdefghijkl"


def letter_under_agent(obs: np.ndarray) -> set[str]:
    """The proposition read off an original-layout observation: letters at the agent's cell."""
    centre = obs.shape[0] // 2
    assert obs[centre, centre, 12] == 1 and obs[..., 12].sum() == 1
    return {LETTERS[c] for c in np.flatnonzero(obs[centre, centre, :12])}


@pytest.mark.parametrize("env_id", ["LetterLTL0-v0", "LetterLTL0-v0.partial"])
def test_make_passes_the_checker_and_uses_the_original_layout(env_id):
    assert set(specrl_jax.list_envs()) <= set(gymnasium.registry)
    env = gymnasium.make(env_id)
    assert isinstance(env.unwrapped, GymEnv)
    assert env.observation_space == gymnasium.spaces.Box(0, 1, (7, 7, 13), np.uint8)
    assert env.action_space == gymnasium.spaces.Discrete(4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.uint8 and obs.shape == (7, 7, 13) and info == {"propositions": set()}
    seen = set()
    for action in np.random.default_rng(0).integers(0, 4, 60):
        obs, reward, terminated, truncated, info = env.step(int(action))
        assert reward == 0.0 and not terminated and not truncated
        assert info["propositions"] == letter_under_agent(obs)
        seen |= info["propositions"]
    assert seen  # some letter was visited, so the comparison above was not vacuous
    env.close()


def test_seeding_horizon_and_action_errors():
    env = gymnasium.make("LetterLTL0-v0", max_steps=4)
    first, _ = env.reset(seed=7)
    trajectory = [env.step(a)[0] for a in (0, 3, 3, 1)]
    again, _ = env.reset(seed=7)
    np.testing.assert_array_equal(first, again)
    for action, expected in zip((0, 3, 3, 1), trajectory):
        obs, _, _, truncated, _ = env.step(action)
        np.testing.assert_array_equal(obs, expected)
    assert truncated
    other, _ = env.reset(seed=8)
    assert not np.array_equal(first, other)
    with pytest.raises(ValueError, match="out of range; accepted values are 0..3"):
        env.unwrapped.step(4)
    with pytest.raises(TypeError, match="integer dtype"):
        env.unwrapped.step(1.5)
    with pytest.raises(ValueError, match="render_mode"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gymnasium warns first that "human" is not listed
        gymnasium.make("LetterLTL0-v0", render_mode="human")


def test_vector_env_steps_all_worlds_and_auto_resets():
    envs = gymnasium.make_vec("LetterLTL0-v0", num_envs=3, max_steps=2)
    assert isinstance(envs.unwrapped, GymVectorEnv)
    assert envs.observation_space.shape == (3, 7, 7, 13)
    obs, _ = envs.reset(seed=1)
    initial = obs
    assert obs.dtype == np.uint8 and len({o.tobytes() for o in obs}) == 3
    previous = obs
    for t in range(2):
        obs, reward, terminated, truncated, info = envs.step(np.array([3, 3, 3]))
        assert reward.tolist() == [0.0] * 3 and not terminated.any()
        assert truncated.tolist() == [t == 1] * 3
        last = info["final_obs"] if t == 1 else obs
        for i in range(3):
            # Moving right shifts the whole torus view one column left.
            np.testing.assert_array_equal(
                last[i, :, :, :12], np.roll(previous[i, :, :, :12], -1, axis=1)
            )
            props = {LETTERS[p] for p in np.flatnonzero(info["propositions"][i])}
            assert props == letter_under_agent(last[i])
        previous = last
    assert info["_final_obs"].tolist() == [True] * 3
    assert not np.array_equal(obs[:, :, :, :12], info["final_obs"][:, :, :, :12])
    assert np.all(obs[:, 3, 3, :12] == 0)  # fresh episodes start on the empty cell (0, 0)
    with pytest.raises(ValueError, match="are not in MultiDiscrete"):
        envs.step(np.array([0, 1, 4]))
    np.testing.assert_array_equal(envs.reset(seed=1)[0], initial)
    envs.close()
