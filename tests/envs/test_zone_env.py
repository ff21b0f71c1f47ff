"""ZoneEnv contract on Point level 0 (the cheapest robot to compile on CPU)."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax.envs.wrappers import AutoReset

BATCH = 3


@pytest.fixture(scope="module")
def world():
    env, params = specrl_jax.make("PointLTL0-v0", max_steps=6)
    auto = AutoReset(env)
    chex.clear_trace_counter()  # other modules' assert_max_traces wrappers count the same methods
    reset = jax.jit(chex.assert_max_traces(env.reset, n=1))
    step = jax.jit(chex.assert_max_traces(auto.step, n=1))
    return env, params, reset, step, jax.jit(env.reset_to)


def action(*values):
    return jnp.asarray(values, jnp.float32)


def test_reset_and_step_trace_once_and_match_spaces(world):
    env, params, reset, step, _ = world
    for seed in range(3):
        obs, state = reset(jax.random.key(seed), params)
        obs, state, reward, terminated, truncated, info = step(
            jax.random.key(seed + 10), state, action(0.3, -0.2), params
        )
    assert env.observation_space.contains(jax.device_get(obs))
    assert obs["ap"].shape == (4, 16) and obs["ego"].shape == (16,)
    assert obs["ap"].dtype == jnp.float32 and obs["ego"].dtype == jnp.float32
    assert reward.dtype == jnp.float32 and float(reward) == 0.0
    assert terminated.dtype == jnp.bool_ and truncated.dtype == jnp.bool_
    assert info["propositions"].shape == (4,) and info["propositions"].dtype == jnp.bool_
    assert state.time.dtype == jnp.int32
    assert env.propositions == ("blue", "green", "magenta", "yellow")


def test_same_key_same_episode_other_key_other_layout(world):
    env, params, reset, _, _ = world
    a, _ = reset(jax.random.key(1), params)
    b, _ = reset(jax.random.key(1), params)
    c, state_c = reset(jax.random.key(2), params)
    chex.assert_trees_all_equal(a, b)
    assert not np.allclose(a["ap"], c["ap"])
    layout = env.layout(state_c)
    assert 0.0 <= float(layout["agent_yaw"]) < 2 * np.pi
    assert layout["zone_xy"].shape == (8, 2) and layout["zone_color"].tolist() == [1, 1, 3, 3, 0, 0, 2, 2]


def test_reset_to_reproduces_the_layout_and_a_hand_built_start(world):
    env, params, reset, _, reset_to = world
    obs, state = reset(jax.random.key(5), params)
    obs2, _ = reset_to(jax.random.key(0), env.layout(state), params)
    chex.assert_trees_all_close(obs, obs2, atol=1e-6)
    # At rest: the accelerometer reads gravity, the magnetometer R^T (0, -0.5, 0).
    layout = dict(env.layout(state), agent_xy=jnp.array([0.0, 0.0]), agent_yaw=jnp.array(np.pi / 2))
    obs, _ = reset_to(jax.random.key(0), layout, params)
    ego = np.asarray(obs["ego"])  # accelerometer, gyro, magnetometer, velocimeter, wall
    np.testing.assert_allclose(ego[0:3], [0, 0, 9.81], atol=1e-4)
    np.testing.assert_allclose(ego[6:9], [-0.5, 0, 0], atol=1e-5)
    np.testing.assert_allclose(ego[12:16], np.exp(-3.3), rtol=1e-5)


def test_thrust_moves_along_the_heading_and_labels_follow(world):
    env, params, reset, step, reset_to = world
    _, state = reset(jax.random.key(0), params)
    zones = jnp.array([[0.41, 0.0], [-2.0, -2.0], [2.0, 2.0], [2.0, -2.0],
                       [-2.0, 2.0], [0.0, 2.0], [0.0, -2.0], [-2.0, 0.0]])
    layout = dict(env.layout(state), agent_xy=jnp.array([0.0, 0.0]), agent_yaw=jnp.array(0.0),
                  zone_xy=zones)
    obs, state = reset_to(jax.random.key(0), layout, params)
    # zone 0 is green (placed first; proposition 1), dead ahead at 0.41 m: bins 0 and 15
    np.testing.assert_allclose(obs["ap"][1, [0, 15]], np.exp(-0.5 * 0.41), rtol=1e-5)
    assert not np.asarray(obs["ap"][1, 1:9]).any()  # the other green zone, at (-2, -2), reads in bins 9-10
    labels = []
    for t in range(5):
        _, state, _, terminated, truncated, info = step(jax.random.key(t), state, action(1.0, 0.0), params)
        labels.append(info["propositions"].tolist())
        assert not terminated and not truncated
    x, y = np.asarray(state.physics.agent_pos[:2])
    assert 0.01 < x < 0.02 and abs(y) < 1e-6  # 2.9 m/s^2 from rest for 0.1 s
    assert labels[0] == [False, False, False, False] and labels[-1] == [False, True, False, False]


def test_wall_crossing_terminates_with_the_original_reward(world):
    """Crossing |x| or |y| = 3.3 ends the episode with reward -1 (the original wrapper's);
    every other step's reward is 0."""
    env, params, reset, step, reset_to = world
    _, state = reset(jax.random.key(0), params)
    for x, expected in ((3.3, True), (3.29, False), (-3.31, True)):
        layout = dict(env.layout(state), agent_xy=jnp.array([0.0, x]))
        _, start = reset_to(jax.random.key(0), layout, params)
        _, _, reward, terminated, truncated, _ = step(jax.random.key(1), start, action(0.0, 0.0),
                                                      params)
        assert bool(terminated) == expected and not truncated
        assert float(reward) == (-1.0 if expected else 0.0)


def test_horizon_truncates_and_auto_reset_returns_the_final_observation(world):
    env, params, reset, step, _ = world
    obs, state = reset(jax.random.key(3), params)
    start = env.layout(state)["agent_xy"]
    for t in range(params.max_steps):
        previous = state
        obs, state, _, terminated, truncated, info = step(jax.random.key(t), state, action(1.0, 0.5), params)
    assert bool(truncated) and not bool(terminated)
    assert int(state.time) == 0 and not np.allclose(env.layout(state)["agent_xy"], start)
    assert int(previous.time) == params.max_steps - 1
    assert not np.allclose(info["final_observation"]["ego"], obs["ego"])


def test_batch_equals_members_and_long_rollout_stays_finite(world):
    _, params, reset, step, _ = world
    keys = jax.random.split(jax.random.key(7), BATCH)
    _, state_b = jax.vmap(reset, in_axes=(0, None))(keys, params)
    actions = jax.random.uniform(jax.random.key(8), (40, BATCH, 2), minval=-1, maxval=1)
    step_b = jax.jit(jax.vmap(step, in_axes=(0, 0, 0, None)))

    def rollout(carry, inputs):
        state, = carry
        key, act = inputs
        obs, state, _, terminated, truncated, _ = step_b(jax.random.split(key, BATCH), state, act, params)
        return (state,), (obs, terminated | truncated)

    step_keys = jax.random.split(jax.random.key(9), 40)
    (_,), (obs_seq, done) = jax.lax.scan(rollout, (state_b,), (step_keys, actions))
    assert np.isfinite(np.asarray(obs_seq["ego"])).all()
    assert (np.asarray(obs_seq["ap"]) >= 0).all() and (np.asarray(obs_seq["ap"]) <= 1).all()
    assert np.asarray(done).sum() >= BATCH * 5  # horizon 6: several auto-resets per env
    # member 1 stepped alone follows the same path
    _, single = reset(keys[1], params)
    for t in range(3):
        member_keys = jax.random.split(step_keys[t], BATCH)
        obs1, single, *_ = step(member_keys[1], single, actions[t, 1], params)
    # the accelerometer comes out of the contact solve: the batched scan and the single step are
    # different programs, which round it differently (2.6e-4 relative on XLA:CPU's loop emitters)
    chex.assert_trees_all_close(obs1, jax.tree.map(lambda x: x[2, 1], obs_seq), atol=1e-5,
                                rtol=1e-3)


def test_original_flat_layout(world):
    env, params, reset, _, _ = world
    obs, _ = reset(jax.random.key(0), params)
    flat = np.asarray(env.original_observation(obs))
    assert flat.shape == (80,) and env.original_observation_space.shape == (80,)
    assert env.original_observation_space.contains(flat)
    ap, ego = np.asarray(obs["ap"]), np.asarray(obs["ego"])
    np.testing.assert_array_equal(flat[0:3], ego[0:3])  # accelerometer
    np.testing.assert_array_equal(flat[3:19], ap[0])  # blue
    np.testing.assert_array_equal(flat[19:35], ap[1])  # green
    np.testing.assert_array_equal(flat[35:38], ego[3:6])  # gyro
    np.testing.assert_array_equal(flat[38:54], ap[2])  # magenta
    np.testing.assert_array_equal(flat[54:57], ego[6:9])  # magnetometer
    np.testing.assert_array_equal(flat[57:60], ego[9:12])  # velocimeter
    np.testing.assert_array_equal(flat[60:76], ap[3])  # yellow
    np.testing.assert_array_equal(flat[76:80], ego[12:16])  # wall sensor


def test_every_zone_id_is_registered_and_builds():
    ids = [i for i in specrl_jax.list_envs() if "LTL" in i and i[:3] in ("Poi", "Car", "Ant")]
    # Vision IDs: test_zone_camera.py; multi-agent IDs (PointLTL0MA*): test_multi_zone.py
    assert len([i for i in ids if "Vision" not in i and "MA" not in i]) == 36
    sizes = {"Point": 80, "Car": 92, "Ant": 108}
    for env_id in ("CarLTL2-v0.partial_overlap", "AntLTL1-v0.overlap", "PointLTL2-v0.partial"):
        env, params = specrl_jax.make(env_id, horizon=50)
        assert params.max_steps == 50 and env.alphabet.shape[1] == 4
        assert env.original_observation_space.shape == (sizes[env.config.robot],)
    with pytest.raises(ValueError, match="unknown ZoneParams"):
        specrl_jax.make("PointLTL0-v0", max_step=3)
