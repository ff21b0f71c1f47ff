"""Moving zones follow the original's welded zone bodies (`envs/zone/motion.py`): against MuJoCo C
running the original's mocap + weld + free body, against the original's measured transient, and
through the env (start position, labels, layout / reset_to, map-bank resets)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax.envs.zone.config import level_config
from specrl_jax.envs.zone.env import ZoneState
from specrl_jax.envs.zone.models import ROBOTS
from specrl_jax.envs.zone.motion import (
    ORIGINAL_INTEGRATOR,
    make_motion,
    weld_recurrence,
)
from specrl_jax.envs.zone.weld_reference import original_zone_trajectory


def positions_over_time(env, state, times) -> np.ndarray:
    """float[T, Z, 2]: `env.zone_positions` of `state` at each env step in `times`."""
    at = jax.jit(jax.vmap(lambda t: env.zone_positions(state.replace(time=t))))
    return np.asarray(at(jnp.asarray(times, jnp.int32)))


def radius_and_angle(offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radius and angle (from +y towards +x) of planar offsets `[..., 2]`."""
    return np.linalg.norm(offset, axis=-1), np.arctan2(offset[..., 0], offset[..., 1])


@pytest.fixture(scope="module")
def point_l1():
    """PointLTL1-v0 (the benchmark's default zone motion) with its jitted reset and reset_to."""
    env, params = specrl_jax.make("PointLTL1-v0", max_steps=5)
    return env, params, jax.jit(env.reset), jax.jit(env.reset_to)


def hand_layout(env, seed: int) -> ZoneState:
    """Zone part of a state: centres on a 3 m grid, random directions (+-1 where the world's
    zones move) and phases; no physics (`zone_positions` reads none)."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid([-1.5, 0.0, 1.5], [-1.5, 0.0, 1.5]), -1).reshape(-1, 2)
    centre = grid[: env.zone_moving.size] + rng.uniform(-0.2, 0.2, (env.zone_moving.size, 2))
    direction = np.where(env.zone_moving, rng.choice([-1.0, 1.0], env.zone_moving.size), 0.0)
    phase = np.where(env.zone_moving, rng.uniform(0, 2 * np.pi, env.zone_moving.size), 0.0)
    as32 = lambda a: jnp.asarray(a, jnp.float32)
    return ZoneState(None, None, as32(centre), as32(direction), as32(phase), jnp.int32(0))


# ---- against MuJoCo C running the original's weld ------------------------------------------
@pytest.mark.parametrize("env_id", ["PointLTL1-v0", "CarLTL2-v0", "AntLTL2-v0"])
def test_zone_centres_match_mujoco_c_weld_on_the_same_layout(env_id, point_l1):
    if env_id == "PointLTL1-v0":  # a layout from the env's own reset
        env, params, reset, _ = point_l1
        _, state = reset(jax.random.key(0), params)
    else:
        env, _ = specrl_jax.make(env_id)
        state = hand_layout(env, seed=len(env_id))
    assert env.config.zone_motion == "weld"  # the default of the benchmark IDs
    centre, direction, phase = (
        np.asarray(a, np.float64) for a in (state.zone_xy, state.zone_direction, state.zone_phase)
    )
    num_steps = 300  # 6 s (Point) to 30 s (Ant) of sim time: transient and steady state
    yaw = np.random.default_rng(1).uniform(0, 2 * np.pi, len(centre))
    c_xyz = original_zone_trajectory(
        env.config.robot, centre, direction, phase, num_steps, zone_yaw=yaw
    )
    ours = positions_over_time(env, state, np.arange(num_steps + 1))
    error = np.linalg.norm(ours - c_xyz[..., :2], axis=-1)  # [T, Z]
    assert error[:101].max() < 1e-4, error[:101].max()  # the first 100 steps (brief: 1 cm)
    assert error[101:].max() < 1e-4, error[101:].max()  # steady state
    # the comparison has teeth: zones start at their centres and move up to 0.3 m
    moving = direction != 0
    c_offset = np.linalg.norm(c_xyz[:, :, :2] - centre, axis=-1)
    assert np.abs(c_offset[0]).max() < 1e-9 and c_offset[-1, moving].min() > 0.29
    assert (c_offset[:, ~moving] < 1e-6).all()  # level 1's welded static zones stay put
    # the kinematic circle (the old default) misses the original's zones by up to 0.3 m
    circle = make_motion("circle", env.config.robot, 0.3, 2.0, 10)
    times = jnp.arange(num_steps + 1, dtype=jnp.int32)
    circle_xy = centre + np.asarray(
        jax.vmap(lambda t: circle.offsets(t, state.zone_direction, state.zone_phase))(times)
    )
    circle_error = np.linalg.norm(circle_xy - c_xyz[..., :2], axis=-1)[:, moving]
    assert circle_error[0].min() > 0.29 and circle_error[-1].min() > 0.05


def test_closed_form_stays_exact_over_a_long_horizon():
    """float32 closed form against the float64 substep recurrence over 10,000 env steps."""
    motion = make_motion("weld", "Point", 0.3, 2.0, 10)
    a, b = weld_recurrence(ROBOTS["Point"].timestep, ORIGINAL_INTEGRATOR["Point"])
    direction, phase = np.array([1.0, -1.0]), np.array([0.4, 5.1])
    h, num_steps = ROBOTS["Point"].timestep, 10_000
    state = np.zeros((2, 2, 2))  # (p, p') x zone x axis
    check = set(np.geomspace(1, num_steps, 30).astype(int))
    expected = {}
    for n in range(num_steps * 10):
        angle = 2.0 * n * h * direction + phase
        command = 0.3 * np.stack([np.sin(angle), np.cos(angle)], axis=-1)
        state = np.einsum("ij,jzk->izk", a, state) + b[:, None, None] * command
        if (n + 1) % 10 == 0 and (n + 1) // 10 in check:
            expected[(n + 1) // 10] = state[0].copy()
    offsets = jax.jit(jax.vmap(lambda t: motion.offsets(t, jnp.asarray(direction, jnp.float32),
                                                        jnp.asarray(phase, jnp.float32))))
    times = sorted(expected)
    got = np.asarray(offsets(jnp.asarray(times, jnp.int32)))
    np.testing.assert_allclose(got, np.stack([expected[t] for t in times]), atol=2e-5)


# ---- against the original's own run (MuJoCo 2.3.3, `reference/zone_env.md` section 5) -------
ORIGINAL_RADII = {  # radial offset after env steps 1, 2, ..., as printed for the original
    "Point": "0.041 0.095 0.14 0.175 0.203 0.224 0.241 0.253 0.263 0.271 0.277 0.281",
    "Car": "0.10 0.18 0.23 0.25 0.27 0.28 0.29",
    "Ant": "0.20 0.27 0.29 0.295 0.296",
}


@pytest.mark.parametrize("robot", ["Point", "Car", "Ant"])
def test_transient_and_steady_circle_as_measured_on_the_original(robot):
    motion = make_motion("weld", robot, 0.3, 2.0, 10)
    times = jnp.arange(3001, dtype=jnp.int32)
    offsets = np.asarray(jax.vmap(
        lambda t: motion.offsets(t, jnp.array([1.0, -1.0]), jnp.array([0.7, 0.7]))
    )(times))
    radius, angle = radius_and_angle(offsets)
    printed = ORIGINAL_RADII[robot].split()
    measured = np.array([float(v) for v in printed])
    # within the printed rounding (+20%); the Car's 0.23 reads 0.2247 here and in MuJoCo C 4.0
    tolerance = np.array([0.6 * 10.0 ** -len(v.split(".")[1]) for v in printed])
    tolerance[measured == 0.23] = 0.0055 if robot == "Car" else tolerance[measured == 0.23]
    np.testing.assert_array_less(np.abs(radius[1 : len(measured) + 1, 0] - measured), tolerance)
    assert radius[0].max() < 1e-6  # the zone starts at its layout centre
    assert radius.max() <= 0.3  # never beyond `travel` (labels.zones_can_overlap relies on it)
    np.testing.assert_allclose(radius[-100:], 0.296, atol=5e-4)  # steady radius 0.296 m
    # steady lag behind the command applied last (at the last substep's start): ~0.176 rad
    last_command = 2.0 * (np.asarray(times[-100:]) * 10 - 1) * ROBOTS[robot].timestep
    lag = np.mod(last_command + 0.7 - angle[-100:, 0] + np.pi, 2 * np.pi) - np.pi
    np.testing.assert_allclose(lag, 0.176, atol=0.01)
    # direction -1 mirrors direction +1 about the phase's axis
    np.testing.assert_allclose(np.mod(angle[1:, 0] - 0.7, 2 * np.pi),
                               np.mod(0.7 - angle[1:, 1], 2 * np.pi), atol=1e-4)


# ---- through the env ------------------------------------------------------------------------
def test_labels_follow_the_dragged_zone_from_the_layout_centre(point_l1):
    """A zone 0.6 m from the agent whose command starts 0.3 m from it: the original's agent
    starts outside it (the circle would start it inside) and is reached a few steps later."""
    env, params, reset, reset_to = point_l1
    _, state = reset(jax.random.key(0), params)
    layout = {k: np.array(v) for k, v in jax.device_get(env.layout(state)).items()}
    near = np.linalg.norm(layout["zone_xy"], axis=1) < 1.5
    layout["zone_xy"][near] = 2.2  # every zone far from the origin, but...
    layout["zone_xy"][0] = (0.6, 0.0)  # ...green zone 0 (moving), commanded to start at (0.3, 0)
    layout["zone_direction"][0], layout["zone_phase"][0] = 1.0, -np.pi / 2
    layout["agent_xy"] = np.zeros(2)
    _, state = reset_to(jax.random.key(1), layout, params)
    # the agent stays put at zero action: read the labels at each step from the reset state
    labels = jax.jit(jax.vmap(lambda t: env._labels(state.replace(time=t))))(jnp.arange(13))
    green = np.asarray(labels)[:, env.propositions.index("green")]
    assert not green[:3].any() and green[6:].all(), green
    start = positions_over_time(env, state, [0])[0]
    np.testing.assert_allclose(start, layout["zone_xy"], atol=1e-6)


def test_map_bank_resets_and_reset_to_give_the_same_trajectory(point_l1):
    env, params, _, reset_to = point_l1
    banked = env.with_map_bank(jax.random.key(0), params, num_maps=4)
    _, states = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(
        jax.random.split(jax.random.key(3), 3), banked
    )
    times = [0, 1, 3, 40]
    for i in range(3):
        state = jax.tree.map(lambda x: x[i], states)
        layout = env.layout(state)
        _, again = reset_to(jax.random.key(9), layout, params)
        a, b = positions_over_time(env, state, times), positions_over_time(env, again, times)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(a[0], np.asarray(layout["zone_xy"]), atol=1e-6)
        moved = np.linalg.norm(a[-1] - a[0], axis=-1)
        assert (moved[env.zone_moving] > 0.25).all() and (moved[~env.zone_moving] == 0).all()


def test_zone_motion_is_validated():
    with pytest.raises(ValueError, match="unknown zone_motion 'spring'"):
        level_config("Point", 1, zone_motion="spring")
    with pytest.raises(ValueError, match="unknown integrator"):
        weld_recurrence(0.002, "implicit")
