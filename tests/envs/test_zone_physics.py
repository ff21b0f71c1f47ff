"""Physics of the Zone robots: facts of the original, the effect of contact pruning and solver
settings (MuJoCo C), and MJX against MuJoCo C on our models (Point and Car here; the Ant's MJX
check runs on the GPU in benchmarks/zone_physics.py, its CPU compile alone takes minutes)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from specrl_jax.envs.zone import make_zone
from specrl_jax.envs.zone.config import DEFAULT_SOLVERS, level_config
from specrl_jax.envs.zone.models import ROBOTS, Solver, load_model, start_height

#: The original's settings: every geom collides, MuJoCo's default solver.
ORIGINAL = Solver(prune_contacts=False)


def start_qpos(robot: str, rng: np.random.Generator) -> np.ndarray:
    yaw = rng.uniform(0, 2 * np.pi)
    if robot == "Point":
        return np.array([0.0, 0.0, yaw])
    quat = [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
    joints = {"Car": [0, 0, 1, 0, 0, 0],
              "Ant": np.array([0, 1, 0, -1, 0, -1, 0, 1]) * np.pi / 2 + rng.uniform(-0.1, 0.1, 8)}
    return np.array([0, 0, ROBOTS[robot].z_height, *quat, *joints[robot]])


@functools.cache
def zone(robot: str):
    """(env, params, jitted reset, jitted step_env) of the level-0 world, built once."""
    env, params = make_zone(level_config(robot, 0))
    return env, params, jax.jit(env.reset), jax.jit(env.step_env)


def c_rollout(model: mujoco.MjModel, qpos: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Agent body positions after each env step (10 substeps, then mj_forward), MuJoCo C."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    out = []
    for a in actions:
        data.ctrl[:] = a
        for _ in range(10):
            mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        out.append(data.xpos[1].copy())
    return np.array(out)


def test_models_have_the_original_masses_and_sizes():
    for robot, mass, nq, nv, nu in (("Point", 0.00519, 3, 3, 2), ("Car", 0.0304, 13, 11, 2),
                                    ("Ant", 42.26, 15, 14, 8)):
        model = load_model(robot)
        assert model.body_mass.sum() == pytest.approx(mass, rel=2e-3)
        assert (model.nq, model.nv, model.nu) == (nq, nv, nu)


def test_actuators_saturate_as_in_the_original():
    point = load_model("Point")
    for thrust, distance in ((1.0, 0.269), (0.05, 0.269), (0.02, 0.108)):
        x = c_rollout(point, np.zeros(3), np.tile([thrust, 0.0], (25, 1)))
        assert x[-1, 0] == pytest.approx(distance, abs=1e-3)
    car = load_model("Car")
    still = np.array([0, 0, 0.1, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0], float)
    x = c_rollout(car, still, np.tile([1.0, 1.0], (25, 1)))
    assert np.linalg.norm(x[-1, :2]) == pytest.approx(0.68, abs=0.02)
    assert x[-1, 1] < -0.6  # forward is body -y


@pytest.mark.parametrize("robot, steps", [("Point", 50), ("Car", 50), ("Ant", 20)])
def test_pruning_and_solver_settings_keep_the_original_trajectories(robot, steps):
    """Our contact pruning and default solver change no trajectory by more than 1e-4 m
    (random saturating actions; the Ant over 2 s, it is chaotic beyond)."""
    original, ours = load_model(robot, ORIGINAL), load_model(robot, DEFAULT_SOLVERS[robot])
    for seed in range(6):
        rng = np.random.default_rng(seed)
        qpos = start_qpos(robot, rng)
        actions = rng.uniform(-1, 1, (steps, original.nu))
        deviation = np.abs(c_rollout(ours, qpos, actions) - c_rollout(original, qpos, actions))
        assert deviation.max() < 1e-4, (robot, seed, deviation.max())


def test_fewer_car_solver_iterations_would_change_trajectories():
    """Why the Car keeps 10 Newton iterations: with 8 some seeds drift by centimetres."""
    original, fast = load_model("Car", ORIGINAL), load_model("Car", Solver(8, 10, 6))
    rng = np.random.default_rng(1)
    qpos, actions = start_qpos("Car", rng), rng.uniform(-1, 1, (50, 2))
    assert np.abs(c_rollout(fast, qpos, actions) - c_rollout(original, qpos, actions)).max() > 0.01


@pytest.mark.parametrize("robot, steps, bound", [("Point", 50, 2e-3), ("Car", 25, 2e-3)])
def test_mjx_tracks_mujoco_c(robot, steps, bound):
    """Env steps of random actions from the env's reset: MJX (float32) against MuJoCo C
    (float64) on the same model; the fact sheet measured about 1e-3 m for the original. The
    free-running Car departs on some seeds after ~10-40 random-action steps, where its own
    dynamics amplify float32 rounding at a contact event (C started from MJX's state does
    the same; benchmarks/RESULTS.md); `test_mjx_car_steps_agree_with_mujoco_c` covers more."""
    env, params, reset, step = zone(robot)
    rng = np.random.default_rng(1)
    _, state = reset(jax.random.key(0), params)
    start = np.asarray(state.start_qpos, np.float64)
    actions = rng.uniform(-1, 1, (steps, env.robot.action_dim)).astype(np.float32)
    positions = []
    for a in actions:
        _, state, *_ = step(jax.random.key(0), state, jnp.asarray(a), params)
        positions.append(np.asarray(state.physics.agent_pos))
    reference = c_rollout(env.mj_model, start, actions)
    assert np.linalg.norm(reference[-1, :2] - start[:2]) > 0.05  # it moved
    assert np.abs(np.array(positions) - reference).max() < bound


def test_car_start_pose_is_well_posed():
    """The Car starts at its resting height (`start_height`), where its MuJoCo C trajectory
    depends continuously on the start. At the original's spawn height (0.1 m) the wheels and
    caster exactly touch the floor: a 1e-9 m higher start moves the Car by centimetres within
    50 random-action steps on some seeds, in MuJoCo C itself."""
    model = load_model("Car", DEFAULT_SOLVERS["Car"])

    def spread(height: float) -> float:
        worst = 0.0
        for seed in range(8):
            rng = np.random.default_rng(seed)
            qpos = start_qpos("Car", rng)
            actions = rng.uniform(-1, 1, (50, 2))
            qpos[2] = height
            raised = qpos + np.eye(13)[2] * 1e-9
            moved = c_rollout(model, raised, actions) - c_rollout(model, qpos, actions)
            worst = max(worst, float(np.abs(moved).max()))
        return worst

    assert 0.0997 < start_height("Car", model) < 0.1
    assert spread(start_height("Car", model)) < 1e-7
    assert spread(ROBOTS["Car"].z_height) > 1e-2


def test_mjx_car_steps_agree_with_mujoco_c():
    """From the env's reset, each env step of MJX (float32) agrees with MuJoCo C started from
    MJX's state to 1e-5 m, the first step included (from the original's spawn height C finds
    no contact there while MJX finds five: ~1e-3 m). Free-running, the Car's own dynamics
    amplify float32 rounding at some contact events (benchmarks/RESULTS.md), so the per-step
    error is what bounds the model difference over many seeds."""
    env, params, reset, step = zone("Car")
    data = mujoco.MjData(env.mj_model)
    worst = 0.0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        _, state = reset(jax.random.key(seed), params)
        for a in rng.uniform(-1, 1, (50, 2)).astype(np.float32):
            physics = state.physics
            data.qpos[:], data.qvel[:] = np.asarray(physics.qpos), np.asarray(physics.qvel)
            data.qacc_warmstart[:] = np.asarray(physics.qacc_warmstart)
            data.ctrl[:] = a
            for _ in range(10):
                mujoco.mj_step(env.mj_model, data)
            mujoco.mj_forward(env.mj_model, data)
            _, state, *_ = step(jax.random.key(0), state, jnp.asarray(a), params)
            worst = max(worst, float(np.abs(np.asarray(state.physics.agent_pos) - data.xpos[1]).max()))
    assert worst < 1e-5, worst


def test_solver_cone_is_validated():
    assert 'cone="elliptic"' in Solver(cone="elliptic").option()
    with pytest.raises(ValueError, match="cone"):
        Solver(cone="round")


def test_mjx_ant_contact_accelerations_agree_with_c_only_with_an_elliptic_cone():
    """The Ant stands on its foot tips, capsules within 60 degrees of the floor normal. MuJoCo C
    orients such a contact's tangents along the capsule axis, MJX 3.17 along world y; the
    normals, distances, friction and impedances agree. A pyramidal cone (the original's) is not
    rotation-invariant, so MJX's accelerations then differ from C's by several percent; an
    elliptic cone with isotropic friction is, and MJX matches C
    (benchmarks/zone_contact_diff.py; RESULTS.md)."""
    forward = jax.jit(mjx.forward)
    for cone, agree in (("elliptic", True), ("pyramidal", False)):
        model = load_model("Ant", Solver(8, 4, 6, cone=cone))
        data = mujoco.MjData(model)
        data.qpos[:] = model.qpos0
        for _ in range(100):
            mujoco.mj_step(model, data)
        data.ctrl[:] = np.random.default_rng(0).uniform(-1, 1, model.nu)
        mujoco.mj_forward(model, data)
        assert data.ncon == 4
        x = forward(mjx.put_model(model), mjx.put_data(model, data))
        contact = x._impl.contact
        live = np.asarray(contact.dist) < np.asarray(contact.includemargin)
        frames = np.asarray(contact.frame)[live]
        np.testing.assert_allclose(frames[:, 0], data.contact.frame[:, :3], atol=1e-6)
        error = np.abs(np.asarray(x.qacc) - data.qacc).max() / np.abs(data.qacc).max()
        assert (error < 1e-4) if agree else (error > 0.01), (cone, error)
