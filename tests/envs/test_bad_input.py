"""Bad input at env level: rare-map configs, bounded samplers, invalid actions, bad overrides."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import checkify

import specrl_jax
from specrl_jax.envs import batch, checked, letter_maps
from specrl_jax.envs.base import checking
from specrl_jax.envs.letter import LetterConfig, LetterWorld, make_letter_world

# ------------------------------------------------------------------ letter densities and loops


@pytest.mark.parametrize("grid_size,cells", [(13, 84), (15, 112)])
def test_letter_config_rejects_maps_too_rare_to_sample(grid_size, cells):
    # both used to reset never (15x15/112: over 10 minutes, 13x13/84: none within 90 s)
    letters = tuple("abcd")
    counts = (cells // 4,) * 3 + (cells - 3 * (cells // 4),)
    with pytest.raises(ValueError, match=r"too rare to sample.*1 in 10,000.*fewer letter cells"):
        LetterConfig(grid_size=grid_size, view_size=7, letters=letters, counts=counts)


def test_letter_config_keeps_configs_that_reset_quickly():
    # 15x15 with 90 cells: about 3e-4 of placements valid, resets in tens of ms
    config = LetterConfig(grid_size=15, view_size=7, letters=tuple("abcde"), counts=18)
    valid, drawn, board = letter_maps.valid_rate(15, 90)
    assert valid / drawn >= letter_maps.MIN_VALID_RATE and board is not None
    # the fallback is a valid set of the right size (checked by the jitted validity test)
    fallback = jnp.asarray(config.map_spec.fallback, jnp.uint32)
    assert bool(letter_maps.is_valid_board(fallback, 15))
    assert int(jax.lax.population_count(fallback).sum()) == 90
    assert np.asarray(fallback)[0] & 1 == 0  # the start stays empty


def test_map_sampler_gives_up_after_its_round_limit():
    # 3x3 with 8 letter cells: the start's only empty cell cannot serve all 8 letters, never valid
    fallback = (0b110, 0b111, 0b111)
    spec = letter_maps.MapSpec(3, (0,) * 8, fallback=fallback, max_rounds=3)
    board = jax.jit(letter_maps.sample_board, static_argnums=1)(jax.random.key(0), spec)
    assert np.asarray(board).tolist() == list(fallback)
    with checking():  # what `checked(env)` traces under
        error, _ = checkify.checkify(letter_maps.sample_board, errors=checkify.user_checks)(
            jax.random.key(0), spec
        )
    with pytest.raises(checkify.JaxRuntimeError, match="no valid 3x3 map with 8 letter cells"):
        error.throw()


@pytest.mark.parametrize("env_id", ["LetterLTL0-v0", "PointLTL0-v0"])
def test_a_reset_lowers_to_one_program_whatever_the_process_traced_before(env_id):
    # the persistent compilation cache keys programs by their text: a check's process-wide
    # error code in it would make a program traced after others a different program
    env, params = specrl_jax.make(env_id)
    key = jax.random.key(0)

    def lowered() -> str:
        return jax.jit(lambda k, p: env.reset(k, p)).lower(key, params).as_text()

    first = lowered()
    checkify.checkify(lambda x: checkify.check(x > 0, "positive"))(1.0)  # takes an error code
    assert lowered() == first


# ------------------------------------------------------------------ invalid actions


def test_letter_invalid_actions_end_the_episode_on_the_traced_path():
    env, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=2))
    _, state = env.reset(jax.random.key(0), params)
    step = jax.jit(env.step)
    moved_up = step(jax.random.key(1), state, jnp.int32(0), params)
    for action in (7, -5, 4):
        obs, after, _, terminated, truncated, info = step(
            jax.random.key(1), state, jnp.int32(action), params
        )
        assert bool(terminated) and not bool(truncated) and bool(info["invalid_action"])
        # the step is action 0's (up), not a wrapped-around index into the move table
        assert np.array_equal(after.agent, moved_up[1].agent)
    valid = step(jax.random.key(1), state, jnp.int32(3), params)
    assert not bool(valid[3]) and not bool(valid[5]["invalid_action"])
    with pytest.raises(ValueError, match=r"action 7 is out of range; accepted values are 0..3"):
        env.step(jax.random.key(1), state, 7, params)


def test_batched_step_checks_eager_calls_and_flags_traced_ones():
    env, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=2))
    worlds = batch(env, 3)
    _, state = worlds.reset(jax.random.key(0), params)
    actions = jnp.array([0, 7, 2])
    with pytest.raises(ValueError, match=r"action \[0, 7, 2\] is out of range"):
        worlds.step(jax.random.key(1), state, actions, params)
    out = jax.jit(worlds.step)(jax.random.key(1), state, actions, params)
    assert out[3].tolist() == [False, True, False]
    assert out[5]["invalid_action"].tolist() == [False, True, False]
    with pytest.raises(ValueError, match=r"invalid actions in 1 of 3 worlds \(indices \[1\]\)"):
        checked(worlds).step(jax.random.key(1), state, actions, params)
    with pytest.raises(checkify.JaxRuntimeError, match="invalid action 7"):
        checked(env).step(jax.random.key(1), jax.tree.map(lambda x: x[0], state), 7, params)


def test_zone_non_finite_action_ends_the_episode_and_keeps_the_state_finite():
    env, params = specrl_jax.make("PointLTL0-v0")
    _, state = env.reset(jax.random.key(0), params)
    step = jax.jit(env.step)
    for bad in (np.nan, np.inf):
        action = jnp.array([bad, 0.5], jnp.float32)
        obs, after, _, terminated, _, info = step(jax.random.key(1), state, action, params)
        assert bool(terminated) and bool(info["invalid_action"])
        leaves = jax.tree.leaves((obs, after))
        floats = [x for x in leaves if jnp.issubdtype(x.dtype, jnp.floating)]
        assert floats and all(bool(jnp.all(jnp.isfinite(x))) for x in floats)
        # the world can go on from there (a wrapper would reset it; stepping it stays finite)
        obs, _, _, terminated, _, info = step(jax.random.key(2), after, jnp.zeros(2), params)
        assert bool(jnp.all(jnp.isfinite(obs["ego"]))) and not bool(info["invalid_action"])
    with pytest.raises(ValueError, match="contains NaN or inf"):
        env.step(jax.random.key(1), state, jnp.array([np.nan, 0.0]), params)


def test_a_python_list_action_gets_the_projects_message_also_under_jit():
    env, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=2))
    _, state = env.reset(jax.random.key(0), params)
    key = jax.random.key(1)
    message = r"action is a Python list of 1 items holding traced values.*shape \(\) and dtype int32"
    with pytest.raises(TypeError, match=message):
        jax.jit(lambda s, a: env.step(key, s, [a], params))(state, jnp.int32(1))
    with pytest.raises(TypeError, match=r"action is a Python list of 1 items; expected one array"):
        env.step(key, state, [1], params)
    with pytest.raises(TypeError, match=r"action is a Python list of 1 items; expected"):
        checked(env).step(key, state, [1], params)
    worlds = batch(env, 2)
    _, states = worlds.reset(jax.random.key(0), params)
    with pytest.raises(TypeError, match=r"batched action is a Python tuple of 2 items holding "
                                        r"traced values.*shape \(2,\) and dtype int32"):
        jax.jit(lambda s, a: worlds.step(key, s, (a, a), params))(states, jnp.int32(1))
    zone, zone_params = specrl_jax.make("PointLTL0-v0")

    def zone_step(key, action):  # traced only: the error comes before anything compiles
        _, zone_state = zone.reset(key, zone_params)
        return zone.step(key, zone_state, [action[0], action[1]], zone_params)

    with pytest.raises(TypeError, match=r"shape \(2,\) and dtype float32"):
        jax.eval_shape(zone_step, key, jnp.zeros(2))


# ------------------------------------------------------------------ overrides


@pytest.mark.parametrize("env_id", ["PointLTL0-v0", "LetterLTL0-v0"])
@pytest.mark.parametrize("max_steps", [-3, 0, 2.5, True])
def test_bad_max_steps_is_rejected(env_id, max_steps):
    with pytest.raises(ValueError, match=f"max_steps must be a positive int, got {max_steps!r}"):
        specrl_jax.make(env_id, max_steps=max_steps)


def test_unknown_zone_override_is_reported_before_the_world_is_built(monkeypatch):
    from specrl_jax.envs import zone

    def no_build(*args, **kwargs):
        raise AssertionError("the world was built before the overrides were checked")

    monkeypatch.setattr(zone, "ZoneEnv", no_build)
    with pytest.raises(ValueError) as err:
        specrl_jax.make("PointLTL0-v0", max_step=10)
    message = str(err.value)
    assert "unknown ZoneParams fields ['max_step'] (nor ZoneConfig fields)" in message
    assert "ZoneConfig fields" in message and "'zone_radius'" in message
    assert "'max_steps'" in message


@pytest.mark.parametrize(
    "override,pattern",
    [
        ({"extent": float("nan")}, "extent must be a finite number"),
        ({"max_tries": 0.5}, "max_tries must be an int"),
        ({"zones_per_color": 2.5}, "zones_per_color must be one int"),
        ({"zone_radius": float("inf")}, "zone_radius must be one float"),
        ({"travel": -1.0}, "travel must be >= 0"),
    ],
)
def test_bad_zone_numbers_are_rejected(override, pattern):
    with pytest.raises(ValueError, match=pattern):
        specrl_jax.make("PointLTL0-v0", **override)


def test_zone_layouts_too_rare_for_max_restarts_are_rejected():
    with pytest.raises(ValueError, match=r"too rare.*max_restarts=3"):
        specrl_jax.make("PointLTL2-v0", max_restarts=3)


def test_letter_world_builds_after_validation():
    # the default registry world still builds and steps (the estimate runs once per size)
    env = LetterWorld()
    assert env.config.map_spec.fallback is not None


def test_zones_that_cross_the_walls_are_rejected_with_the_accepted_radius():
    from specrl_jax.envs.multi import MultiZoneConfig
    from specrl_jax.envs.zone import ZoneConfig
    from specrl_jax.envs.zone.config import level_config

    # static zones: centres within extent - keepout = 2.5 - 0.55 m, walls at 3.3 m
    with pytest.raises(ValueError, match=r"arena is \+-3.3 m.*zone_radius must be <= 1.35 m"):
        ZoneConfig(zone_radius=3.0)
    assert ZoneConfig(zone_radius=1.35).zone_radius[0] == 1.35
    with pytest.raises(ValueError, match="zones of radius 3.0 m cross the walls"):
        specrl_jax.make("PointLTL0-v0", zone_radius=3.0)
    # moving zones (level 2: keepout 0.7) also travel 0.3 m from their layout centre
    assert level_config("Point", 2, zone_radius=1.2).zone_radius[0] == 1.2
    with pytest.raises(ValueError, match=r"plus travel 0.3.*zone_radius must be <= 1.20 m"):
        level_config("Point", 2, zone_radius=1.25)
    with pytest.raises(ValueError, match="cross the walls"):
        MultiZoneConfig(num_agents=2, zone_radius=3.0)
