"""Arm kinematics and geometry against the reference's neutral-pose table and MuJoCo C."""

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from specrl_jax.envs.arm import ArmConfig, ArmEnv, ArmState, sensors
from specrl_jax.envs.arm import layout as layout_lib
from specrl_jax.envs.arm import model as arm_model

# The original's neutral pose, measured in PyBullet (reference B6): frame origin, COM, COM xyzw
NEUTRAL = {
    "link1": ((-0.6, 0, 0.333), (-0.6, -0.04, 0.283), (0, 0, 0, 1)),
    "link2": ((-0.6, 0, 0.333), (-0.58406, 0.06, 0.36968), (-0.6923, 0.14394, 0.14394, 0.6923)),
    "link3": ((-0.47404, 0, 0.62281), (-0.4848, 0.01, 0.57297), (0, 0.20357, 0, 0.97906)),
    "link4": ((-0.39838, 0, 0.58992), (-0.35615, -0.02, 0.594), (-0.30169, -0.63952, 0.63952, -0.30169)),
    "link5": ((-0.04956, 0, 0.4094), (-0.14217, 0.04, 0.48571), (0, 0.90441, 0, 0.42666)),
    "link6": ((-0.04956, 0, 0.4094), (-0.00956, 0, 0.4094), (0.70711, 0, 0, 0.70711)),
    "link7": ((0.03844, 0, 0.4094), (0.03844, 0, 0.3294), (0.923, -0.38481, 0, 0)),
    "hand": ((0.03844, 0, 0.3024), (0.03844, 0, 0.2624), (1, -0.0023, 0, 0)),
    "leftfinger": ((0.03844, 0, 0.244), (0.03839, -0.01, 0.224), (1, -0.0023, 0, 0)),
    "rightfinger": ((0.03844, 0, 0.244), (0.03849, 0.01, 0.224), (1, -0.0023, 0, 0)),
}


@pytest.fixture(scope="module")
def env():
    return ArmEnv(ArmConfig(mode=1))


def _state(env, qpos, centres=None):
    """An arm at rest at `qpos` (built directly: an eager `reset_to` would run MJX op by op)."""
    centres = np.zeros((8, 3)) + 5.0 if centres is None else centres
    qpos = jnp.asarray(qpos, jnp.float32)
    return ArmState(physics=env.physics.init(qpos), region_pos=jnp.asarray(centres, jnp.float32),
                    start_qpos=qpos, layout_ok=jnp.array(True), time=jnp.zeros((), jnp.int32))


def test_neutral_pose_matches_the_original_table(env):
    pose = jax.jit(env.poses)(_state(env, arm_model.NEUTRAL_QPOS))
    for i, name in enumerate(arm_model.LINK_BODIES):
        frame, com, quat = (np.asarray(v) for v in NEUTRAL[name])
        assert np.abs(pose["link_pos"][i] - frame).max() < 1e-4, name
        assert np.abs(pose["com_pos"][i] - com).max() < 1e-4, name
        q = np.asarray(pose["com_quat"][i])
        assert min(np.abs(q - quat).max(), np.abs(q + quat).max()) < 1e-4, name  # sign is free
    assert np.abs(pose["grasp_pos"] - np.array([0.03844, 0, 0.1974])).max() < 1e-4
    assert np.abs(pose["grasp_vel"]).max() == 0.0


def test_forward_kinematics_match_mujoco_c_on_random_joints(env):
    model = arm_model.load_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    poses = jax.jit(env.poses)
    ids = arm_model.body_ids(model)
    site = model.site(arm_model.GRASP_SITE).id
    for _ in range(5):
        qpos = rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1])
        qvel = rng.uniform(-1, 1, 7)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        jacp = np.zeros((3, 7))
        mujoco.mj_jacSite(model, data, jacp, None, site)
        state = _state(env, qpos)
        state = state.replace(physics=state.physics.replace(qvel=jnp.asarray(qvel, jnp.float32)))
        pose = poses(state)
        assert np.abs(pose["link_pos"] - data.xpos[ids]).max() < 2e-5
        assert np.abs(pose["com_pos"] - data.xipos[ids]).max() < 2e-5
        assert np.abs(pose["link_mat"].reshape(-1, 9) - data.xmat[ids]).max() < 2e-5
        assert np.abs(pose["grasp_vel"] - jacp @ qvel).max() < 2e-5  # m/s


def _model_with_ball(radius):
    """The arm with full (not vertex-capped) hulls and a mocap sphere, for mj_geomDistance."""
    xml = re.sub(r' maxhullvert="\d+"', "", arm_model.MODEL_PATH.read_text())
    spec = mujoco.MjSpec.from_string(xml)
    spec.meshdir = str(arm_model.HULL_DIR)
    ball = spec.worldbody.add_body(name="ball", mocap=True)
    ball.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0])
    return spec.compile()


def test_link_sphere_distances_match_mujoco_c_geom_distance(env):
    """The env's own distance path (`link_sphere_distances` over `env._triangles`, the per-link
    hulls as one HullSet, all 10 links at once as `_observe` calls it) against MuJoCo C."""
    assert isinstance(env._triangles, tuple) and len(env._triangles) == 10  # the HullSet branch
    model = _model_with_ball(0.06)
    data = mujoco.MjData(model)
    ids = arm_model.body_ids(model)
    distances = jax.jit(lambda pos, mat, centres: sensors.link_sphere_distances(
        pos, mat, env._triangles, centres, jnp.array([0.06])))
    rng = np.random.default_rng(1)
    signs = []
    for trial in range(30):
        data.qpos[:] = arm_model.NEUTRAL_QPOS + rng.uniform(-0.6, 0.6, 7)
        mujoco.mj_kinematics(model, data)
        link = trial % 10
        centre = data.xpos[ids[link]] + rng.normal(0.0, 0.07, 3)
        data.mocap_pos[0] = centre
        mujoco.mj_kinematics(model, data)
        dist, normal = distances(data.xpos[ids], data.xmat[ids].reshape(-1, 3, 3), centre[None])
        for other in range(10):  # every link, the probed one near the sphere
            fromto = np.zeros(6)
            ref = mujoco.mj_geomDistance(model, data, model.geom(arm_model.LINK_BODIES[other]).id,
                                         model.geom("ball").id, 10.0, fromto)
            ours = float(dist[other, 0])
            assert abs(ours - ref) < 1e-3, (trial, other, ours, ref)
            if ref > 1e-3:  # the direction from the link's point toward the sphere's
                expected = (fromto[3:] - fromto[:3]) / np.linalg.norm(fromto[3:] - fromto[:3])
                assert np.abs(np.asarray(normal[other, 0]) - expected).max() < 1e-3
            if other == link:
                signs.append(ref < 0)
    assert 0 < sum(signs) < len(signs)  # both penetrating and separated cases were checked


def test_link_sphere_distances_match_pybullet_less_its_collision_margin(env):
    """PyBullet's own `getClosestPoints` (the original's mode-1 labels and features; stored by
    `benchmarks/lab/arm_vs_pybullet.py --write-reference`: 24 poses, 8 spheres of 0.06 m near the
    grasp target) against the env's distances: PyBullet's are ours less its collision margin,
    1.0 mm (measured 0.971-1.001 mm), on every pair within 10 cm, penetrating ones included."""
    reference = np.load(Path(__file__).parent / "data" / "arm_pybullet_rollouts.npz")
    theirs = reference["dist_pybullet"]

    def distances(qpos, centres):
        pose = env.poses(_state(env, qpos, centres))
        radius = jnp.asarray(env.region_radius)
        return sensors.link_sphere_distances(pose["link_pos"], pose["link_mat"], env._triangles,
                                             jnp.asarray(centres), radius)[0]

    ours = np.asarray(jax.jit(jax.vmap(distances))(
        jnp.asarray(reference["dist_qpos"], jnp.float32),
        jnp.asarray(reference["dist_centres"], jnp.float32)))
    near = np.abs(theirs) < 0.1
    assert near.sum() > 400 and (theirs[near] < 0).sum() > 20
    assert np.abs(theirs - ours + 1e-3)[near].max() < 1e-4, np.abs(theirs - ours + 1e-3)[near].max()


def test_keepout_test_matches_mujoco_c_on_the_neutral_robot():
    config = ArmConfig()
    model = _model_with_ball(config.region_radius)
    data = mujoco.MjData(model)
    data.qpos[:] = arm_model.NEUTRAL_QPOS
    hulls = [model.geom(name).id for name in ("link0",) + arm_model.LINK_BODIES]
    rng = np.random.default_rng(2)
    centres = rng.uniform([-0.5, -0.3, 0.06], [0.2, 0.3, 0.56], (60, 3))
    ours = np.asarray(jax.jit(jax.vmap(lambda c: layout_lib.keepout_ok(c, config)))(centres))
    points = layout_lib.neutral_obstacles()[1]
    for centre, ok in zip(centres, ours):
        data.mocap_pos[0] = centre
        mujoco.mj_kinematics(model, data)
        gaps = [mujoco.mj_geomDistance(model, data, g, model.geom("ball").id, 10.0, None) for g in hulls]
        near_point = np.linalg.norm(points - centre, axis=1).min() <= 0.14
        expected = min(gaps) > config.keepout and not near_point
        if abs(min(gaps) - config.keepout) > 1e-5:
            assert ok == expected, (centre, min(gaps))
    assert 0.2 < ours.mean() < 0.9  # the test saw both sides


@pytest.mark.parametrize("partial", [False, True])
def test_mode1_features_and_labels_match_a_numpy_reference(env, partial):
    """Hand-built layouts: a region at the fingertips (both fingers, also the hand), one at the
    elbow (arm only), one just below the fingertips (grippers only, as measured in the
    original), one beside either finger (that finger only: no label), the rest far; features
    checked against the B4/B5 formulas (`exp(-2 d)`, or the `.partial` IDs' linear 0.25 m
    feature with dir zeroed beyond it) from the env's poses."""
    if partial:
        env = ArmEnv(ArmConfig(mode=1, partial=True))
    state = _state(env, arm_model.NEUTRAL_QPOS)
    pose = jax.jit(env.poses)(state)
    tip = np.asarray(pose["link_pos"][8]) + np.array([0, 0, -0.054])
    elbow = np.asarray(pose["link_pos"][3])
    cases = {
        "both": (tip + [0, 0, 0.02], {"arm_magenta", "grippers_magenta"}),
        "below": (tip + [0, 0, -0.058], {"grippers_magenta"}),
        "elbow": (elbow, {"arm_magenta"}),
        "left finger": (tip + [0, -0.06, -0.025], set()),
        "right finger": (tip + [0, 0.06, -0.025], set()),
    }
    observe = jax.jit(env._observe)
    zeroed = 0
    for name, (centre, expected) in cases.items():
        centres = np.array([[0.0, 0.0, 3.0 + i] for i in range(8)])
        centres[0] = centre  # a magenta region
        obs, label = observe(_state(env, arm_model.NEUTRAL_QPOS, centres))
        on = {p for p, v in zip(env.propositions, np.asarray(label)) if v}
        assert on == expected, (name, on)
        # numpy reference of the features from the env's own distances
        dist, normal = sensors.link_sphere_distances(
            pose["link_pos"], pose["link_mat"], env._triangles, jnp.asarray(centres),
            jnp.full(8, 0.06))
        dist, normal = np.asarray(dist), np.asarray(normal)
        if name.endswith("finger"):  # exactly one finger inside the region, by millimetres
            assert sorted(dist[8:, 0] < -0.003) == [False, True] and (dist[8:, 0] > 0.003).any()
        for p, prop in enumerate(env.propositions):
            part, color = prop.split("_")
            regions = [z for z in range(8) if env.config.colors[env.region_color[z]] == color]
            links = range(8) if part == "arm" else range(8, 10)
            for row, link in enumerate(links):
                z = min(regions, key=lambda z: dist[link, z])
                d = dist[link, z]
                direction = normal[link, z] * (-1 if d < 0 else 1)
                f = max(0.0, 0.25 - d) / 0.25 if partial else np.exp(-2 * d)
                if partial and f == 0:
                    direction, zeroed = np.zeros(3), zeroed + 1
                ref = np.r_[direction, f]
                assert np.abs(np.asarray(obs["ap"][p, row]) - ref).max() < 1e-4, (name, prop, row)
            if part == "grippers":
                assert np.all(np.asarray(obs["ap"][p, 2:]) == 0)
    assert zeroed > 0 or not partial  # the far regions exercised the zeroed direction


def test_mode0_features_and_labels_match_a_numpy_reference():
    for partial in (False, True):
        env = ArmEnv(ArmConfig(mode=0, partial=partial))
        grasp = np.array([0.03844, 0.0, 0.1974])
        centres = np.array([[0.0, 0.0, 3.0 + i] for i in range(8)])
        centres[0] = grasp + [0.1, 0, 0]  # magenta, centre 0.1 m away (the reference's probes)
        centres[3] = grasp + [0, 0.05, 0]  # yellow, grasp target inside
        centres[4] = grasp + [0, 0, 0.3]  # blue, centre 0.3 m away
        centres[6] = grasp + [0, -0.4, 0]  # green, centre 0.4 m away
        obs, label = jax.jit(env._observe)(_state(env, arm_model.NEUTRAL_QPOS, centres))
        assert {p for p, v in zip(env.propositions, np.asarray(label)) if v} == {"yellow"}
        for p, color in enumerate(env.propositions):
            zs = [z for z in range(8) if env.config.colors[env.region_color[z]] == color]
            rays = centres[zs] - grasp
            ray = rays[np.argmin(np.linalg.norm(rays, axis=1))]
            m = max(0.0, np.linalg.norm(ray) - 0.06)
            if partial:
                unit = ray / np.linalg.norm(ray) if 0 < m <= 0.25 else np.zeros(3)
                ref = np.r_[unit, max(0.0, 0.25 - m) / 0.25]
            else:
                ref = np.r_[ray / np.linalg.norm(ray) if m > 0 else np.zeros(3), np.exp(-2 * m)]
            assert np.abs(np.asarray(obs["ap"][p]) - ref).max() < 1e-5, (color, partial)
        if partial:  # the values the reference measured in the original
            dist = {c: float(obs["ap"][env.propositions.index(c), 3]) for c in env.propositions}
            assert dist == pytest.approx(
                {"magenta": 0.84, "blue": 0.04, "green": 0.0, "yellow": 1.0}, abs=1e-5)
            assert np.all(np.asarray(obs["ap"][env.propositions.index("green")]) == 0)
