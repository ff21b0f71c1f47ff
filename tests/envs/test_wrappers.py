"""The generic wrappers and the registry, exercised on LetterWorld."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax.envs import registry
from specrl_jax.envs.wrappers import AutoReset, BatchedEnv, EpisodeStatistics, batch


@pytest.fixture(scope="module")
def letter():
    env, params = specrl_jax.make("LetterLTL0-v0")
    return env, params.replace(max_steps=3)


def test_auto_reset_truncates_at_the_horizon_and_starts_a_fresh_map(letter):
    env, params = letter
    wrapped = AutoReset(env)
    obs, state = jax.jit(wrapped.reset)(jax.random.key(0), params)
    step = jax.jit(wrapped.step)
    for t in range(1, 4):
        previous = state
        obs, state, _, terminated, truncated, info = step(
            jax.random.key(t), state, jnp.int32(3), params
        )
        assert not terminated and bool(truncated) == (t == 3)
    # The step that truncates reports the finished episode and returns a fresh one.
    np.testing.assert_array_equal(
        info["final_observation"]["ap"],
        env.observe(previous.replace(agent=previous.agent.at[1].set(3), time=previous.time + 1))[
            "ap"
        ],
    )
    assert int(state.time) == 0 and state.agent.tolist() == [0, 0]
    assert not np.array_equal(state.letters, previous.letters)
    fresh = env.observe(state)
    jax.tree.map(np.testing.assert_array_equal, obs, fresh)
    np.testing.assert_array_equal(info["propositions"], info["final_info"]["propositions"])


def test_episode_statistics_and_batching_with_a_map_bank(letter):
    env, params = letter
    params = env.with_map_bank(jax.random.key(2), params, num_maps=16)
    assert params.map_bank.shape == (16, 7, 7) and params.map_bank.dtype == jnp.int8
    batched = BatchedEnv(EpisodeStatistics(AutoReset(env)), num_envs=4)
    obs, state = jax.jit(batched.reset)(jax.random.key(1), params)
    assert obs["ap"].shape == (4, 7, 7, 12) and state.env_state.letters.shape == (4, 7, 7)
    geometries = {(np.asarray(g) >= 0).tobytes() for g in state.env_state.letters}
    assert len(geometries) > 1
    step = jax.jit(batched.step)
    for t in range(7):
        actions = batched.sample_actions(jax.random.key(100 + t))
        obs, state, _, _, truncated, info = step(jax.random.key(t), state, actions, params)
        assert truncated.shape == (4,) and bool(np.all(truncated)) == (t in (2, 5))
    assert info["episode_length"].tolist() == [3] * 4
    assert state.episode_length.tolist() == [1] * 4
    with pytest.raises(ValueError, match=r"batched action has shape \(3,\); expected \(4,\)"):
        batched.step(jax.random.key(0), state, jnp.zeros(3, jnp.int32), params)
    with pytest.raises(ValueError, match="num_envs must be a positive int"):
        batch(env, 0)
    with pytest.raises(ValueError, match="num_maps must be a positive int"):
        env.with_map_bank(jax.random.key(0), params, num_maps=0)


@pytest.mark.parametrize(
    "action, error, message",
    [
        (jnp.zeros((2,), jnp.int32), ValueError, r"shape \(2,\); expected shape \(\)"),
        (jnp.float32(1.0), TypeError, "expected an integer dtype for Discrete"),
        (jnp.int32(4), ValueError, r"action 4 is out of range; accepted values are 0..3"),
        (jnp.int32(-1), ValueError, "out of range"),
    ],
)
def test_step_rejects_bad_actions(letter, action, error, message):
    env, params = letter
    _, state = env.reset_to(
        jax.random.key(0),
        {"letters": -np.ones((7, 7), np.int32), "agent": np.zeros(2, np.int32)},
        params,
    )
    with pytest.raises(error, match=message):
        env.step(jax.random.key(0), state, action, params)


def test_registry_errors_and_listing():
    assert {"LetterLTL0-v0", "LetterLTL0-v0.partial"} <= set(specrl_jax.list_envs())
    with pytest.raises(
        ValueError, match=r"unknown env ID 'LetterLTL1-v0'.*Did you mean 'LetterLTL0-v0'"
    ):
        specrl_jax.make("LetterLTL1-v0")
    with pytest.raises(TypeError, match="env ID must be a string, got int"):
        specrl_jax.make(3)
    with pytest.raises(ValueError, match="already registered"):
        registry.register("LetterLTL0-v0", lambda: None)


def test_make_validates_the_overrides_of_every_family_before_building(monkeypatch):
    """`registry.make` is the one place that checks an ID's overrides: unknown names are
    listed with the accepted ones, names the ID fixes and bad horizons are refused, and the
    family's factory is not called before."""
    cases = {
        "LetterLTL0-v0": ("LetterParams", "LetterConfig", "grid_size"),
        "PointLTL0-v0": ("ZoneParams", "ZoneConfig", "zone_radius"),
        "PandaLTLReach0-v0": ("ArmParams", "ArmConfig", "region_radius"),
        "PointLTL0MA2-v0": ("MultiZoneParams", "MultiZoneConfig", "collisions"),
    }
    table = registry._family_table()
    for env_id, (params, config, field) in cases.items():
        _, description, accepted = table[env_id]
        assert accepted is not None

        def no_build(**overrides):
            raise AssertionError("the factory ran before the overrides were checked")

        monkeypatch.setitem(table, env_id, (no_build, description, accepted))
        with pytest.raises(ValueError) as err:
            specrl_jax.make(env_id, max_step=5)
        message = str(err.value)
        assert message.startswith(
            f"unknown {params} fields ['max_step'] (nor {config} fields) for {env_id!r}; "
            f"accepted: {config} fields ["
        )
        assert f"'{field}'" in message and "did you mean 'max_steps'" in message
        with pytest.raises(ValueError, match="max_steps must be a positive int, got 0"):
            specrl_jax.make(env_id, max_steps=0)
    # names an ID fixes (the level's keepout and moving zones used to fail deep in ZoneConfig)
    for env_id, name in (("PointLTL1-v0", "zone_keepout"), ("PointLTL1-v0", "moving_per_color"),
                         ("PandaLTLReach0-v0", "control"), ("PointLTL0MA2-v0", "robot")):
        with pytest.raises(ValueError, match=rf"\['{name}'\] are fixed by the env ID '{env_id}'"):
            specrl_jax.make(env_id, **{name: 1})


def test_registered_factories_are_validated_by_make():
    from specrl_jax.envs.letter import LetterConfig, LetterParams, make_letter_world

    calls = []

    def factory(**overrides):
        calls.append(overrides)
        return make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=2),
                                 **overrides)

    accepted = registry.Overrides(LetterConfig, LetterParams, fixed=("grid_size",))
    registry.register("TinyLetter-v0", factory, "5x5", accepted)
    try:
        with pytest.raises(ValueError, match="fixed by the env ID 'TinyLetter-v0'"):
            specrl_jax.make("TinyLetter-v0", grid_size=7)
        with pytest.raises(ValueError, match=r"unknown LetterParams fields \['horizon'\]"):
            specrl_jax.make("TinyLetter-v0", horizon=7)
        assert calls == []
        env, params = specrl_jax.make("TinyLetter-v0", max_steps=9)
        assert params.max_steps == 9 and env.config.grid_size == 5 and calls == [{"max_steps": 9}]
    finally:
        registry._EXTRA.pop("TinyLetter-v0")
