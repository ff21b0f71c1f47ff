"""LetterWorld: movement, labels, views against a numpy reference, determinism, batching, config."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax.envs.letter import LetterConfig, LetterWorld

IDS = ["LetterLTL0-v0", "LetterLTL0-v0.partial"]


def reference_observation(letters: np.ndarray, agent: np.ndarray, view: int) -> np.ndarray:
    """The original's view: every cell shifted to centre the agent, then cropped; uint8[V, V, 13]."""
    n = letters.shape[0]
    centre, delta = n // 2, (n - view) // 2
    full = np.zeros((n, n, 13), np.uint8)
    for i, j in np.argwhere(letters >= 0):
        full[(i + centre - agent[0]) % n, (j + centre - agent[1]) % n, letters[i, j]] = 1
    full[centre, centre, 12] = 1
    return full[delta : delta + view, delta : delta + view]


class Compiled:
    """One jitted reset/step per env, counting traces."""

    def __init__(self, env_id: str):
        self.env, self.params = specrl_jax.make(env_id)
        self.traces = {"reset": 0, "step": 0}

        def reset(key, params):
            self.traces["reset"] += 1
            return self.env.reset(key, params)

        def step(key, state, action, params):
            self.traces["step"] += 1
            return self.env.step(key, state, action, params)

        self.reset, self.step = jax.jit(reset), jax.jit(step)

    def rollout(self, key: jax.Array, num_steps: int):
        key_reset, key_actions = jax.random.split(key)
        obs, state = self.reset(key_reset, self.params)
        actions = jax.random.randint(key_actions, (num_steps,), 0, 4)
        trajectory = [(obs, state, None, None)]
        for t in range(num_steps):
            obs, state, reward, terminated, truncated, info = self.step(
                jax.random.key(t), state, actions[t], self.params
            )
            trajectory.append((obs, state, info, (reward, terminated, truncated)))
        return actions, trajectory


@pytest.fixture(scope="module", params=IDS)
def compiled(request) -> Compiled:
    return Compiled(request.param)


def test_rollout_matches_numpy_reference(compiled):
    env = compiled.env
    n, v = env.config.grid_size, env.config.view
    actions, trajectory = compiled.rollout(jax.random.key(0), 40)
    letters = np.asarray(trajectory[0][1].letters)
    agent = np.zeros(2, int)
    moves = {0: (-1, 0), 1: (1, 0), 2: (0, -1), 3: (0, 1)}
    for t, (obs, state, info, outs) in enumerate(trajectory):
        if t > 0:
            agent = (agent + moves[int(actions[t - 1])]) % n
            expected_props = np.zeros(12, bool)
            if letters[tuple(agent)] >= 0:
                expected_props[letters[tuple(agent)]] = True
            np.testing.assert_array_equal(info["propositions"], expected_props)
            assert int(info["symbol"]) == letters[tuple(agent)] + 1  # its row of env.alphabet
            np.testing.assert_array_equal(env.alphabet[info["symbol"]], expected_props)
            reward, terminated, truncated = outs
            assert float(reward) == 0.0 and not terminated and not truncated
        np.testing.assert_array_equal(state.agent, agent)
        np.testing.assert_array_equal(state.letters, letters)  # letters never move
        assert int(state.time) == t
        assert env.observation_space.contains(jax.device_get(obs))
        np.testing.assert_array_equal(
            env.original_observation(obs), reference_observation(letters, agent, v)
        )
    assert compiled.traces == {"reset": 1, "step": 1}


def test_moves_wrap_around_the_torus():
    for env_id, n in (("LetterLTL0-v0", 7), ("LetterLTL0-v0.partial", 15)):
        env, params = specrl_jax.make(env_id)
        letters = -np.ones((n, n), np.int32)
        letters[n - 1, 0], letters[0, n - 1], letters[1, 0], letters[0, 1] = 0, 1, 2, 3
        _, state = env.reset_to(
            jax.random.key(0), {"letters": letters, "agent": np.zeros(2, np.int32)}, params
        )
        expected = {0: ((n - 1, 0), 0), 1: ((1, 0), 2), 2: ((0, n - 1), 1), 3: ((0, 1), 3)}
        for action, (cell, letter) in expected.items():
            _, moved, *_, info = env.step(jax.random.key(1), state, jnp.int32(action), params)
            np.testing.assert_array_equal(moved.agent, cell)
            assert np.flatnonzero(info["propositions"]).tolist() == [letter]
        # The agent may stand on a letter: both its channel and the agent channel at the centre.
        _, on_letter = env.reset_to(
            jax.random.key(0), {"letters": letters, "agent": np.array([1, 0])}, params
        )
        obs = env.observe(on_letter)
        centre = env.config.view // 2
        assert obs["ap"][centre, centre].tolist() == [0, 0, 1] + [0] * 9
        assert obs["ego"][centre, centre, 0] == 1 and obs["ego"].sum() == 1


def test_layout_round_trip_and_reset_to_errors():
    env, params = specrl_jax.make("LetterLTL0-v0")
    obs, state = jax.jit(env.reset)(jax.random.key(3), params)
    layout = env.layout(state)
    assert layout["letters"].dtype == jnp.int32 and layout["letters"].shape == (7, 7)
    assert layout["agent"].tolist() == [0, 0]
    obs_again, state_again = env.reset_to(jax.random.key(9), layout, params)
    jax.tree.map(np.testing.assert_array_equal, (obs, state), (obs_again, state_again))
    bad = [
        ({"letters": layout["letters"]}, ValueError, "keys"),
        ({"letters": np.zeros((6, 7), int), "agent": layout["agent"]}, ValueError, "shape"),
        ({"letters": np.full((7, 7), 12), "agent": layout["agent"]}, ValueError, "accepted -1..11"),
        ({"letters": layout["letters"], "agent": np.array([0, 7])}, ValueError, "accepted 0..6"),
        ({"letters": layout["letters"], "agent": np.array([0.0, 1.0])}, TypeError, "integers"),
    ]
    for layout_bad, error, message in bad:
        with pytest.raises(error, match=message):
            env.reset_to(jax.random.key(0), layout_bad, params)


def test_determinism_and_fresh_maps():
    env, params = specrl_jax.make("LetterLTL0-v0")
    reset = jax.jit(env.reset)
    _, first = reset(jax.random.key(11), params)
    _, again = reset(jax.random.key(11), params)
    _, other = reset(jax.random.key(12), params)
    np.testing.assert_array_equal(first.letters, again.letters)
    assert not np.array_equal(first.letters, other.letters)


def test_vmap_agrees_with_single_steps():
    env, params = specrl_jax.make("LetterLTL0-v0.partial")
    keys = jax.random.split(jax.random.key(4), 3)
    actions = jnp.array([0, 2, 3], jnp.int32)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    obs_b, state_b = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)
    out_b = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))(keys, state_b, actions, params)
    for i in range(3):
        obs_i, state_i = reset(keys[i], params)
        jax.tree.map(lambda b, s, i=i: np.testing.assert_array_equal(b[i], s), obs_b, obs_i)
        out_i = step(keys[i], state_i, actions[i], params)
        jax.tree.map(lambda b, s, i=i: np.testing.assert_array_equal(b[i], s), out_b, out_i)


def test_alphabet_propositions_and_spaces():
    env, _ = specrl_jax.make("LetterLTL0-v0")
    assert env.propositions == tuple("abcdefghijkl")
    alphabet = np.asarray(env.alphabet)
    assert alphabet.shape == (13, 12) and alphabet.dtype == bool
    assert not alphabet[0].any() and np.array_equal(alphabet[1:], np.eye(12, dtype=bool))
    assert env.original_observation_space.shape == (7, 7, 13)
    assert env.original_observation_space.dtype == np.uint8


def test_custom_config_scales_propositions():
    env, params = specrl_jax.make(
        "LetterLTL0-v0", grid_size=9, letters=("x", "y", "z"), counts=(1, 2, 3), max_steps=10
    )
    assert env.config.view == 9 and params.max_steps == 10 and env.alphabet.shape == (4, 3)
    obs, state = jax.jit(env.reset)(jax.random.key(0), params)
    assert obs["ap"].shape == (9, 9, 3)
    np.testing.assert_array_equal(
        np.bincount(np.asarray(state.letters)[state.letters >= 0]), [1, 2, 3]
    )


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"grid_size": 8}, "grid_size must be odd"),
        ({"grid_size": 40}, "grid_size must be an int in 3..32"),
        ({"grid_size": 15, "view_size": 6}, "view_size must be an odd int"),
        ({"grid_size": 7, "view_size": 9}, "view_size must be an odd int in 1..grid_size=7"),
        ({"letters": ("a", "a")}, "distinct"),
        ({"letters": ()}, "non-empty"),
        ({"counts": (1, 2)}, "one positive int per letter"),
        ({"counts": 3}, "do not fit a 7x7 grid"),
    ],
)
def test_config_validation(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LetterConfig(**kwargs)


def test_make_rejects_unknown_options_and_bad_horizon():
    with pytest.raises(ValueError, match="unknown LetterParams fields.*'colour'.*accepted"):
        specrl_jax.make("LetterLTL0-v0", colour=3)
    with pytest.raises(ValueError, match="max_steps must be a positive int"):
        specrl_jax.make("LetterLTL0-v0", max_steps=0)
    with pytest.raises(TypeError, match="LetterConfig"):
        LetterWorld({"grid_size": 7})
