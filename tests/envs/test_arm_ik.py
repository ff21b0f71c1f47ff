"""End-effector control (`PandaLTLReach{0,1}-v0`): our IK against a float64 transcription of
PyBullet's iteration on MuJoCo C kinematics and against PyBullet's own results, and the
end-effector IDs through make and Gymnasium."""

import warnings
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax
from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.ik import DOWN, EndEffectorIK, rotation_error


def _reference_ik(model, q, target, iterations=20, residual=1e-4, damping=0.5):
    """PyBullet's calculateInverseKinematics (position + orientation, default arguments) as
    bullet3 writes it, in float64 on MuJoCo C's kinematics of the same model."""
    data = mujoco.MjData(model)
    site = model.site(arm_model.GRASP_SITE).id
    hand = model.body("hand").id
    down = np.array([0.0, 1.0, 0.0, 0.0])  # wxyz of xyzw (1, 0, 0, 0)
    q = np.array(q, np.float64)
    last = np.inf
    for _ in range(iterations):
        if last <= residual:
            break
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        jacp, jacr = np.zeros((3, 7)), np.zeros((3, 7))
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        current = data.xquat[hand].copy()
        inverse = current * np.array([1, -1, -1, -1])
        delta = np.zeros(4)
        mujoco.mju_mulQuat(delta, down, inverse)
        angle = 2 * np.arccos(np.clip(delta[0], -1, 1))
        if angle > np.pi:
            angle -= 2 * np.pi
        sin = np.sqrt(max(1 - delta[0] ** 2, 0.0))
        axis = delta[1:] / sin if sin**2 >= 10 * np.finfo(float).eps else np.array([1.0, 0, 0])
        error = np.concatenate([target - data.site_xpos[site], angle * axis])
        jac = np.concatenate([jacp, jacr])
        dq = np.linalg.solve(jac.T @ jac + damping * np.eye(7), jac.T @ error)
        dq *= min(1.0, (np.pi / 4) / np.abs(dq).max())
        last = np.linalg.norm(target - data.site_xpos[site])
        q = q + dq
    return q


@pytest.fixture(scope="module")
def ik():
    return EndEffectorIK(arm_model.load_model())


def test_rotation_error_is_the_shorter_rotation():
    about_x = lambda a: jnp.array([np.cos(a / 2), np.sin(a / 2), 0.0, 0.0])
    np.testing.assert_allclose(rotation_error(about_x(0.3), about_x(0.5)), [0.2, 0, 0], atol=1e-6)
    # 350 degrees apart one way is 10 degrees the other
    np.testing.assert_allclose(rotation_error(about_x(0.0), about_x(np.radians(350))),
                               [-np.radians(10), 0, 0], atol=1e-5)
    np.testing.assert_allclose(rotation_error(jnp.asarray(DOWN), jnp.asarray(DOWN)), 0, atol=1e-7)


def test_ik_matches_pybullets_iteration_on_mujoco_c(ik):
    model = arm_model.load_model()
    rng = np.random.default_rng(0)
    solve = jax.jit(ik.solve)
    pose = jax.jit(ik.pose)
    neutral = arm_model.NEUTRAL_QPOS
    for q in [neutral] + [neutral + rng.uniform(-0.3, 0.3, 7) for _ in range(3)]:
        point = np.asarray(pose(jnp.asarray(q, jnp.float32))[0], np.float64)
        target = point + 0.05 * rng.uniform(-1, 1, 3)
        ours = np.asarray(solve(jnp.asarray(q, jnp.float32), jnp.asarray(target, jnp.float32)))
        ref = _reference_ik(model, q, target)
        assert np.abs(ours - ref).max() < 2e-3, (ours, ref)
        if q is neutral:  # gripper already down: the damped iterations close most of the gap
            # (from a tilted start they turn the gripper down first, PyBullet's as ours)
            reached = np.asarray(pose(jnp.asarray(ours))[0])
            assert np.linalg.norm(reached - target) < 0.5 * np.linalg.norm(point - target)


def test_ik_and_grasp_target_match_pybullet_itself(ik):
    """PyBullet's `calculateInverseKinematics` and grasp-target FK (stored by
    `benchmarks/lab/arm_vs_pybullet.py --write-reference`: 32 configurations within 0.3 rad of the
    neutral pose, targets up to 5 cm away, gripper down) against ours: measured 6e-7 rad and
    3e-7 m."""
    reference = np.load(Path(__file__).parent / "data" / "arm_pybullet_rollouts.npz")
    qpos = jnp.asarray(reference["ik_qpos"], jnp.float32)
    points = jax.jit(jax.vmap(lambda q: ik.pose(q)[0]))(qpos)
    solved = jax.jit(jax.vmap(ik.solve))(qpos, jnp.asarray(reference["ik_targets"], jnp.float32))
    np.testing.assert_allclose(points, reference["ik_grasp_target"], atol=1e-5)
    np.testing.assert_allclose(solved, reference["ik_joints"], atol=1e-5)
    assert np.abs(reference["ik_joints"] - reference["ik_qpos"]).max() > 0.01  # the IK moved


def test_joint_targets_move_the_grasp_target_by_the_action(ik):
    q = jnp.asarray(arm_model.NEUTRAL_QPOS, jnp.float32)
    targets = jax.jit(ik.joint_targets)
    start = np.asarray(ik.pose(q)[0])
    for action, expected in (([0, -1.0, 0.5], [0, -0.05, 0.025]), ([0, 0, -1.0], [0, 0, -0.05])):
        moved = np.asarray(ik.pose(targets(q, jnp.asarray(action)))[0]) - start
        np.testing.assert_allclose(moved, expected, atol=3e-3)
    # along +x the stretched neutral arm gets 0.035 of the 0.05 m in PyBullet's 20 iterations
    moved = np.asarray(ik.pose(targets(q, jnp.array([1.0, 0.0, 0.0])))[0]) - start
    assert 0.03 < moved[0] < 0.05 and np.abs(moved[1:]).max() < 3e-3, moved
    # the target height is clipped at the table top (z >= 0)
    q_down = q
    for _ in range(6):  # 6 x 5 cm down, asking for the table and below
        q_down = targets(q_down, jnp.array([0.0, 0.0, -1.0]))
    assert float(ik.pose(q_down)[0][2]) > -2e-3


EE_IDS = ("PandaLTLReach0-v0", "PandaLTLReach0-v0.partial", "PandaLTLReach1-v0",
          "PandaLTLReach1-v0.partial")


def test_end_effector_ids_build_with_a_3d_action():
    for env_id in EE_IDS:
        env, params = specrl_jax.make(env_id)
        assert env.config.control == "ee" and env.action_space.shape == (3,)
        assert env.config.mode == int(env_id[13])
        assert env.config.partial == env_id.endswith(".partial")
        assert params.max_steps == 200
        assert env.observation_space["ego"].shape == ((6,) if env.config.mode == 0 else (70,))
    assert specrl_jax.make("PandaLTLReach0Joints-v0")[0].action_space.shape == (7,)
    with pytest.raises(ValueError, match="fixed by the env ID"):
        specrl_jax.make("PandaLTLReach0-v0", control="joints")
    with pytest.raises(ValueError, match="control must be one of"):
        specrl_jax.envs.arm.ArmConfig(control="torque")
    with pytest.raises(ValueError, match="motor_solve must be one of .*'pallas'"):
        specrl_jax.envs.arm.ArmConfig(motor_solve="triton")
    assert specrl_jax.make("PandaLTLReach0Joints-v0", motor_solve="pallas")[0].physics.motor_solve == "pallas"
    assert specrl_jax.make("PandaLTLReach0Joints-v0")[0].physics.motor_solve == "auto"  # the kernel on a GPU


def test_end_effector_step_and_gymnasium_bridge():
    """One ee ID through the Gymnasium bridge (checker, reset, a step that moves the grasp
    target 5 cm along +x as the action asks)."""
    import specrl_jax.gym  # noqa: F401  (registers the IDs)

    env = gymnasium.make("PandaLTLReach0-v0", table_contacts=False, layouts_per_round=64)
    assert env.action_space.shape == (3,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs["ego_state"][:3], [0.03844, 0, 0.1974], atol=1e-4)
    for _ in range(3):
        obs, reward, terminated, truncated, _ = env.step(np.array([1.0, 0, 0], np.float32))
    assert reward == 0.0 and not terminated and not truncated
    moved = obs["ego_state"][:3] - np.array([0.03844, 0, 0.1974])
    # three steps of 5 cm asked; the IK gives about 3.5 cm of each along x (above), the motor
    # tracks most of that (the gains of the joint IDs)
    assert 0.04 < moved[0] < 0.15 and abs(moved[1]) < 0.01 and abs(moved[2]) < 0.02, moved
