"""End-effector control: the original's action -> joint targets, through PyBullet's IK.

The original's end-effector IDs (`PandaLTLReach{0,1}-v0`) move the grasp target by `0.05 a`
(a in [-1, 1]^3, metres), clip the target height at z >= 0, and ask PyBullet's
`calculateInverseKinematics` (no optional arguments) for joint angles that put the grasp target
there with the gripper pointing down (orientation xyzw (1, 0, 0, 0)); those angles are the joint
targets of the position motor for the step. PyBullet's IK, as in bullet3's
`PhysicsServerCommandProcessor::processCalculateInverseKinematicsCommand` and
`IKTrajectoryHelper::computeIK`, starting from the current joint angles:

  repeat at most 20 times, while the last position error exceeds 1e-4 m:
    e = [target position - p(q); rotation vector of (target orientation * orientation(q)^-1)]
    J = [position Jacobian; rotation Jacobian] of the grasp target (6 x dof)
    dq = (J^T J + 0.5 I)^-1 J^T e         (damped least squares, damping 0.5 per joint)
    dq *= min(1, (pi/4) / max|dq|)        (at most 45 degrees per joint and iteration)
    q = q + dq

The fingers' two DoF have zero Jacobian columns for the grasp target, so their rows decouple and
stay put; the 7 arm joints solve the same 7-column problem. Joint limits are not applied.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.kinematics import ChainKinematics

EE_STEP = 0.05  # metres of grasp-target displacement per unit action
ITERATIONS = 20
RESIDUAL = 1e-4  # metres
DAMPING = 0.5
MAX_STEP = math.pi / 4  # rad per joint and iteration
#: gripper pointing down: xyzw (1, 0, 0, 0), as wxyz
DOWN = np.array([0.0, 1.0, 0.0, 0.0])


def rotation_error(current: jax.Array, target: jax.Array) -> jax.Array:
    """float[3]: the rotation vector (rad, world frame) of `target * current^-1`, the shorter
    way round, for wxyz unit quaternions (Bullet's angle-axis of the quaternion difference)."""
    cw, cv = current[0], -current[1:]  # conjugate of current
    tw, tv = target[0], target[1:]
    w = tw * cw - jnp.dot(tv, cv)
    v = tw * cv + cw * tv + jnp.cross(tv, cv)
    v = jnp.where(w < 0, -v, v)  # the same rotation with w >= 0: angle in [0, pi]
    norm = jnp.linalg.norm(v)
    angle = 2.0 * jnp.arctan2(norm, jnp.abs(w))
    return jnp.where(norm > 1e-12, angle / jnp.where(norm > 1e-12, norm, 1.0), 0.0) * v


class EndEffectorIK:
    """Joint targets for an end-effector displacement, PyBullet's way (see the module)."""

    def __init__(self, model: mujoco.MjModel):
        self.kinematics = ChainKinematics(model)
        self._hand = int(model.body("hand").id)
        self._site_pos = np.asarray(model.site(arm_model.GRASP_SITE).pos, np.float32)
        self._body_of_joint = np.asarray(model.jnt_bodyid, np.int32)

    def pose(self, qpos: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """Grasp-target position float[3] (m), its orientation float[4] (wxyz, the hand's) and
        the 6 x 7 Jacobian (position rows, then rotation rows) at joint angles `qpos`."""
        frames = self.kinematics.frames(qpos)
        point = frames.xpos[self._hand] + frames.xmat[self._hand] @ self._site_pos
        jacp = jnp.cross(frames.xaxis, point - frames.xanchor)  # [7, 3]
        return point, frames.xquat[self._hand], jnp.concatenate([jacp.T, frames.xaxis.T], axis=0)

    def solve(self, qpos: jax.Array, target: jax.Array,
              orientation: jax.Array | None = None) -> jax.Array:
        """float[7] joint angles (rad) from PyBullet's IK iterations, started at `qpos`, toward
        the grasp-target position `target: float[3]` (m) and `orientation` (wxyz; default
        gripper down)."""
        orientation = jnp.asarray(DOWN) if orientation is None else orientation

        def iteration(_, carry):
            q, last_error = carry
            active = last_error > RESIDUAL
            point, quat, jac = self.pose(q)
            error = jnp.concatenate([target - point, rotation_error(quat, orientation)])
            normal = jac.T @ jac + DAMPING * jnp.eye(q.shape[0])
            dq = jnp.linalg.solve(normal, jac.T @ error)
            dq = dq * jnp.minimum(1.0, MAX_STEP / jnp.maximum(jnp.max(jnp.abs(dq)), 1e-12))
            position_error = jnp.linalg.norm(target - point)
            return (jnp.where(active, q + dq, q),
                    jnp.where(active, position_error, last_error))

        q, _ = jax.lax.fori_loop(0, ITERATIONS, iteration, (qpos, jnp.array(jnp.inf)))
        return q

    def joint_targets(self, qpos: jax.Array, action: jax.Array) -> jax.Array:
        """float[7]: the original's joint targets for the ee action `action: float[3]` (already
        clipped to [-1, 1]) from joint angles `qpos: float[7]`."""
        point, _, _ = self.pose(qpos)
        target = point + EE_STEP * action
        target = target.at[2].set(jnp.maximum(target[2], 0.0))
        return self.solve(qpos, target)


__all__ = ["DOWN", "EE_STEP", "EndEffectorIK", "rotation_error"]
