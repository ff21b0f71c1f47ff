"""Physics of the Zone robots: facts of the original, the effect of contact pruning and solver
settings (MuJoCo C), MuJoCo C's capsule contact frame in MJX, and MJX against MuJoCo C on our
models (the Ant over a few env steps here; longer in benchmarks/lab/zone_physics.py)."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from envs.ant_states import settled_ant
from mujoco import mjx
from mujoco.mjx._src import collision_driver, collision_primitive

from specrl_jax.envs.zone import contact_frame, make_zone, small_linalg
from specrl_jax.envs.zone.c_reference import classic_rk4_step
from specrl_jax.envs.zone.config import DEFAULT_SOLVERS, level_config
from specrl_jax.envs.zone.models import ROBOTS, Solver, load_model, start_height
from specrl_jax.envs.zone.physics import Physics, PhysicsState
from specrl_jax.gym import GymEnv

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


#: a world per robot (the physics is the robot's whatever the level); those of test_zone_gym.py
GYM_IDS = {"Point": "PointLTL2-v0.partial_overlap", "Car": "CarLTL0-v0", "Ant": "AntLTL0-v0"}


@functools.cache
def zone(robot: str):
    """(env, params, jitted reset, jitted step) of the robot's world in `GYM_IDS`: the Gymnasium
    bridge's compiled functions, which tests/envs/test_zone_gym.py compiles for the same worlds,
    so that each robot's reset and step compile once in the suite."""
    bridge = GymEnv(GYM_IDS[robot], physics="jax")  # the bounds here are MJX-JAX's
    reset = lambda key, params: bridge._reset(key, params)[:2]  # (obs, state), without the label
    return bridge.env, bridge.params, reset, bridge._step


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
    free-running float32 Car departs on some seeds after ~10-40 random-action steps, where its
    dynamics amplify MJX's float32 errors (C's own spread under float32-sized perturbations
    stays ~1e-6 m there; docs/fidelity.md); `test_mjx_car_steps_agree_with_mujoco_c` and
    `test_mjx_car_in_float64_tracks_c_within_cs_own_spread` cover more."""
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
    amplify float32 rounding at some contact events (docs/fidelity.md), so the per-step
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


def test_mjx_car_in_float64_tracks_c_within_cs_own_spread():
    """The Car's model, free of float32: MJX in float64 from the env's reset, 40 env steps of
    random actions, 8 seeds, stays within 3x MuJoCo C's own spread plus 1e-6 m, the spread
    being the largest departure of 4 copies of C whose qpos and qvel change by one float32
    rounding step (a random +-2^-24 relative) after every env step. Measured: MJX <= 1.5e-7 m,
    spread 3e-7 to 1.4e-6 m. In float32, MJX departs by 4e-3 to 0.18 m on 3 of these seeds
    where the spread stays ~1e-6 (a float32 effect, not C's sensitivity); in float64, seed 7
    departs at step 41 by a one-step error of 1.4e-5 m, cause not found (docs/fidelity.md)."""
    worst = []
    with jax.enable_x64(True):
        env, params = make_zone(level_config("Car", 0, physics="jax"))
        reset, step = jax.jit(env.reset), jax.jit(env.step_env)
        for seed in range(8):
            rng, rng_perturb = np.random.default_rng(seed), np.random.default_rng(10_000 + seed)
            _, state = reset(jax.random.key(seed), params)
            assert state.physics.qpos.dtype == jnp.float64
            runs = [mujoco.MjData(env.mj_model) for _ in range(5)]  # C, then 4 perturbed copies
            for data in runs:
                data.qpos[:] = np.asarray(state.start_qpos)
            deviation, spread = 0.0, 0.0
            for a in rng.uniform(-1, 1, (40, 2)).astype(np.float32):
                _, state, *_ = step(jax.random.key(0), state, jnp.asarray(a), params)
                for data in runs:
                    data.ctrl[:] = a
                    for _ in range(10):
                        mujoco.mj_step(env.mj_model, data)
                    mujoco.mj_forward(env.mj_model, data)
                for data in runs[1:]:
                    for field in (data.qpos, data.qvel):
                        field *= 1 + rng_perturb.choice([-1.0, 1.0], field.shape) * 2.0**-24
                reference = runs[0].xpos[1]
                torso = np.asarray(state.physics.agent_pos)
                deviation = max(deviation, np.abs(torso - reference).max())
                spread = max(spread, max(np.abs(d.xpos[1] - reference).max() for d in runs[1:]))
            worst.append((deviation, spread))
    worst = np.array(worst)
    assert (worst[:, 0] <= 3 * worst[:, 1] + 1e-6).all(), worst


def test_solver_cone_is_validated():
    assert 'cone="elliptic"' in Solver(cone="elliptic").option()
    with pytest.raises(ValueError, match="cone"):
        Solver(cone="round")


def quat(axis: list[float], angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis]


def test_capsule_contact_frame_is_mujoco_cs():
    """Our capsule-plane collider gives MuJoCo C's contacts (distance, position, frame) for a
    capsule upright (C's fallback tangent x), tilted by 17 and 60 degrees from the normal,
    lying along x, and upside down. MJX 3.17's own collider differs where the capsule is
    within 30 degrees of the normal (projected axis shorter than 0.5)."""
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom type="plane" size="5 5 .1"/><body><freejoint/>'
        '<geom type="capsule" size="0.05 0.2"/></body></worldbody></mujoco>')
    data = mujoco.MjData(model)
    poses = ((quat([1, 0, 0], 0), 0.24), (quat([1, 1, 0], 0.3), 0.2), (quat([1, -2, 0], 1.05), 0.1),
             (quat([0, 1, 0], np.pi / 2), 0.04), (quat([0, 1, 0], np.pi), 0.24))
    pair = jnp.array([[0, 1]])
    mjx_differs = []
    for q, z in poses:
        data.qpos[:] = [0.3, -0.2, z, *q]
        mujoco.mj_forward(model, data)
        assert data.ncon >= 1
        mx, dx = mjx.put_model(model), mjx.put_data(model, data)
        ours = [np.asarray(a) for a in contact_frame.plane_capsule(mx, dx, None, pair)]
        theirs = np.asarray(collision_primitive.plane_capsule(mx, dx, None, pair)[2])
        for i in range(data.ncon):
            j = np.abs(ours[1] - data.contact.pos[i]).sum(1).argmin()
            assert ours[0][j] == pytest.approx(data.contact.dist[i], abs=1e-6)
            np.testing.assert_allclose(ours[1][j], data.contact.pos[i], atol=1e-6)
            np.testing.assert_allclose(ours[2][j].ravel(), data.contact.frame[i], atol=1e-6)
            mjx_differs.append(np.abs(theirs[j].ravel() - data.contact.frame[i]).max() > 0.1)
    assert mjx_differs == [True, True, False, False, False, True]


def test_c_contact_frame_is_scoped_and_guarded(monkeypatch):
    """Only the Ant has capsule-floor pairs, so only its physics traces under our collider; the
    table holds MJX's collider outside a block (also after an error inside one); an MJX whose
    table is not as expected fails at `Physics` construction."""
    assert [contact_frame.plane_capsule_pairs(load_model(r)) for r in ROBOTS] == [0, 0, 8]
    key, mjx_own = contact_frame.KEY, collision_primitive.plane_capsule
    with pytest.raises(KeyError), contact_frame.c_contact_frame():
        assert collision_driver._COLLISION_FUNC[key] is contact_frame.plane_capsule
        with contact_frame.c_contact_frame():
            pass
        raise KeyError("inside")
    assert collision_driver._COLLISION_FUNC[key] is mjx_own
    monkeypatch.setitem(collision_driver._COLLISION_FUNC, key, lambda m, d, k, g: None)
    with pytest.raises(RuntimeError, match="not collision_primitive.plane_capsule"):
        Physics(load_model("Ant"))
    assert not Physics(load_model("Car")).c_contact_frame  # no capsules: not checked, not used


def test_mjx_ant_contact_accelerations_agree_with_c():
    """At a settled Ant state (4 foot contacts, capsules ~10 degrees from the floor normal), our
    MJX forward pass equals MuJoCo C's with the original's pyramidal cone and with an elliptic
    one. MJX 3.17's own capsule frame (world y as first tangent) departs by ~12% of qacc under
    the pyramidal cone, which is not rotation-invariant (benchmarks/zone_contact_diff.py, in git
    history)."""
    variants = (("pyramidal", True, 0), ("elliptic", True, 0), ("pyramidal", False, 0),
                ("pyramidal", True, 4))
    for cone, c_frame, cap in variants:
        model = load_model("Ant", Solver(8, 4, 6, cone=cone, max_contacts=cap))
        data = settled_ant(model)
        # a fresh function per trace: jax.jit would reuse a trace of mjx.forward made outside
        forward = jax.jit(lambda m, d: mjx.forward(m, d))
        scope = contact_frame.c_contact_frame() if c_frame else contextlib.nullcontext()
        with scope:
            x = forward(mjx.put_model(model), mjx.put_data(model, data))
        contact = x._impl.contact
        assert contact.dist.shape == ((cap or 17),)  # the cap: 4 contact slots instead of 17
        live = np.asarray(contact.dist) < np.asarray(contact.includemargin)
        frames = np.asarray(contact.frame)[live].reshape(-1, 9)
        error = np.abs(np.asarray(x.qacc) - data.qacc).max() / np.abs(data.qacc).max()
        if c_frame:
            np.testing.assert_allclose(frames, data.contact.frame, atol=1e-6)
            assert error < 1e-5, (cone, error)
        else:
            np.testing.assert_allclose(frames[:, :3], data.contact.frame[:, :3], atol=1e-6)
            assert error > 0.05, error


def test_mjx_ant_tracks_mujoco_c():
    """From the env's reset, MJX (float32, C's contact frame) against MuJoCo C (float64) on the
    same model under random actions, 4 seeds. Against the classic RK4 on C's forward dynamics
    (the scheme MJX implements, see `classic_rk4_step`), 10 env steps (1 s): torso within
    1e-4 m, joints within 1e-3 rad (measured offline: 2e-5 m, 1.3e-4 rad on 6 seeds). Against MuJoCo C
    4.0's own RK4 step, 3 env steps: torso within 2e-4 m, joints within 5e-4 rad (measured 2e-5
    m, 4e-5 rad; MJX's own contact frame is off by 7e-4 m and 3e-3 rad after one step); C 4.0's
    RK4 departs from the classic one by ~1e-2 m within 10 steps (docs/fidelity.md)."""
    env, params, reset, step = zone("Ant")
    assert env.physics.c_contact_frame
    worst = np.zeros(4)  # torso, joints against classic RK4 (10 steps), against C 4.0 (3 steps)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        _, state = reset(jax.random.key(seed), params)
        c_rk4, c_own = mujoco.MjData(env.mj_model), mujoco.MjData(env.mj_model)
        c_rk4.qpos[:] = c_own.qpos[:] = np.asarray(state.start_qpos, np.float64)
        contacts = 0
        for t, a in enumerate(rng.uniform(-1, 1, (10, 8)).astype(np.float32)):
            _, state, *_ = step(jax.random.key(0), state, jnp.asarray(a), params)
            c_rk4.ctrl[:] = c_own.ctrl[:] = a
            for _ in range(10):
                classic_rk4_step(env.mj_model, c_rk4)
                mujoco.mj_step(env.mj_model, c_own)
                contacts = max(contacts, c_own.ncon)
            torso, qpos = np.asarray(state.physics.agent_pos), np.asarray(state.physics.qpos)
            for i, data in ((0, c_rk4), (2, c_own)):
                if i == 2 and t >= 3:
                    continue
                mujoco.mj_forward(env.mj_model, data)
                worst[i] = max(worst[i], np.abs(torso - data.xpos[1]).max())
                worst[i + 1] = max(worst[i + 1], np.abs(qpos[7:] - data.qpos[7:]).max())
        assert contacts >= 2  # the feet hit the floor (it bounces: contacts come and go)
    assert (worst < [1e-4, 1e-3, 2e-4, 5e-4]).all(), worst


_BOX = """<mujoco><option timestep="0.004"/><worldbody><geom type="plane" size="2 2 .1"/>
<body pos="0 0 0.05"><freejoint/><geom type="box" size=".05 .05 .05"/><site name="s"/>
<body pos="0.1 0 0"><joint name="hinge" axis="0 1 0" range="-1 1" limited="true"/>
<geom type="capsule" fromto="0 0 0 0.1 0 0" size=".02"/></body></body></worldbody>
<actuator><motor joint="hinge" gear="2"/></actuator>
<sensor><accelerometer site="s"/><gyro site="s"/><jointpos joint="hinge"/></sensor></mujoco>"""


@functools.cache
def _box_step(**options) -> tuple[Physics, Callable]:
    """`Physics(box, **options)` and its jitted step, shared by the tests below (one trace and
    compile each)."""
    physics = Physics(mujoco.MjModel.from_xml_string(_BOX), **options)
    return physics, jax.jit(physics.step)


def _box_start(model: mujoco.MjModel) -> PhysicsState:
    """The box at rest at qpos0 (a step reads only qpos, qvel and the warm start)."""
    zeros = lambda *shape: jnp.zeros(shape, jnp.float32)
    return PhysicsState(jnp.asarray(model.qpos0, jnp.float32), zeros(model.nv), zeros(model.nv),
                        zeros(3), jnp.eye(3), zeros(model.nsensordata))


def test_sensor_free_substeps_and_unroll_give_the_same_steps():
    """Skipping the sensors in the substeps (the default) and unrolling the substep loop give
    bitwise the same physics and sensors as MJX's own `step` with sensors in every substep and
    a plain loop (a box with a hinged capsule on the floor, 3 env steps)."""
    model = mujoco.MjModel.from_xml_string(_BOX)
    runs = {}
    for name, kw in (("mjx", dict(substep_sensors=True)), ("ours", dict(unroll=2))):
        physics, step = _box_step(**kw)
        state, out = _box_start(model), []
        for ctrl in (1.0, -1.0, 0.5):
            state = step(state, jnp.array([ctrl]))
            out.append(np.concatenate([np.asarray(state.qpos), np.asarray(state.sensordata)]))
        runs[name] = np.array(out)
    assert physics.substep_model is not physics.model
    np.testing.assert_array_equal(runs["ours"], runs["mjx"])
    assert np.abs(runs["mjx"][1:, -3:] - runs["mjx"][:-1, -3:]).max() > 1e-3  # sensors change
    accelerometer = runs["mjx"][:, model.nq:model.nq + 3]
    assert np.abs(accelerometer).max() > 1.0  # computed, not left at zero


@pytest.mark.parametrize("robot, episodes, steps", [("Car", 2, 400), ("Ant", 4, 250)])
def test_solver_contact_cap_drops_no_contact_of_a_live_robot(robot, episodes, steps):
    """`DEFAULT_SOLVERS[robot].max_contacts` (MJX passes only that many contacts, the deepest,
    to the solver) is never exceeded in MuJoCo C while the robot is live: episodes of uniform,
    bang-bang (held 5 steps) and sinusoidal actions from the env's start pose, every substep,
    until the Ant's fall (torso <= 0.08 m) ends one; the cap is reached, so it is no larger than
    needed."""
    model = load_model(robot, DEFAULT_SOLVERS[robot])
    cap = DEFAULT_SOLVERS[robot].max_contacts
    data = mujoco.MjData(model)
    most = 0
    for episode in range(episodes):
        rng = np.random.default_rng(episode)
        mujoco.mj_resetData(model, data)
        data.qpos[:] = start_qpos(robot, rng)
        data.qpos[2] = start_height(robot, model)
        phase = rng.uniform(0, 2 * np.pi, model.nu)
        for t in range(steps):
            mode = episode % 3
            if mode == 0:
                data.ctrl[:] = rng.uniform(-1, 1, model.nu)
            elif mode == 1 and t % 5 == 0:
                data.ctrl[:] = rng.choice([-1.0, 1.0], model.nu)
            elif mode == 2:
                data.ctrl[:] = np.sin(0.2 * np.pi * t + phase)
            counts = []
            for _ in range(10):
                mujoco.mj_step(model, data)
                counts.append(data.ncon)
            if robot == "Ant" and data.xpos[1][2] <= 0.08:
                break
            most = max(most, *counts)
    assert most == cap, (robot, most, cap)


def test_small_cholesky_replaces_the_library_calls_and_matches_them():
    """`small_linalg`: factor and solve equal `jax.scipy.linalg`'s to float32 rounding (n = 11
    and 14, both triangles, vmapped); inside `Physics` with `small_cholesky` the traced step has
    no library Cholesky or triangular solve left, and the library's are back after tracing."""
    rng = np.random.default_rng(0)
    solve = jax.jit(jax.vmap(lambda m, v: [small_linalg.cho_solve(
        small_linalg.cho_factor(m, lower=lower), v) for lower in (False, True)]))
    for n in (11, 14):
        a = rng.normal(size=(3, n, n)).astype(np.float32)
        a = a @ np.swapaxes(a, 1, 2) + n * np.eye(n, dtype=np.float32)
        b = rng.normal(size=(3, n)).astype(np.float32)
        expected = np.linalg.solve(a, b[..., None])[..., 0]
        for ours in solve(a, b):  # upper, then lower triangle
            np.testing.assert_allclose(ours, expected, rtol=1e-4, atol=1e-5)
    start = _box_start(mujoco.MjModel.from_xml_string(_BOX))
    for small in (False, True):  # the first is the step traced by the test above
        _, step = _box_step(unroll=2, **({"small_cholesky": True} if small else {}))
        jaxpr = str(step.trace(start, jnp.array([0.0])).jaxpr)
        assert ("cholesky" in jaxpr and "triangular_solve" in jaxpr) != small
    assert jax.scipy.linalg.cho_factor is not small_linalg.cho_factor
