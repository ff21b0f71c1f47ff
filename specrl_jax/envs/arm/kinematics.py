"""Forward kinematics of the arm's serial chain, written out body by body.

MJX's generic `kinematics` walks the body tree level by level with gathers and concatenations;
for this 13-body chain XLA turns it into about ten thousand scalar operations (a 1.5 MB HLO
module; 2.7 s for 16 arms on a 2-core CPU, which dominated the whole physics step). Here the
same quantities (MuJoCo's conventions: `xquat` wxyz, `xmat` world <- body) come from a Python
loop over the static chain on quaternions, each step an array operation rather than a scalar
formula: a body's quaternion is its parent's times fixed 4 x 4 maps (the body offset, the
joint's cosine and sine parts), its origin the parent's plus the rotated (constant) offset; the
3 x 3 matrices of all bodies follow in one vectorised formula. Products with constants are
written as a broadcast multiply and a sum, which XLA fuses (a `dot` would become a library
matrix product per body on a GPU). A body costs about twenty array operations.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.zone.mjx_import import mjx


def _quat_to_mat(quat: np.ndarray) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
    return mat.reshape(3, 3)


def _right_product(b: np.ndarray) -> np.ndarray:
    """float64[4, 4]: the matrix of `q -> q * b` (Hamilton product of wxyz quaternions)."""
    out = np.zeros((4, 4))
    for k in range(4):
        column = np.zeros(4)
        mujoco.mju_mulQuat(column, np.eye(4)[k], np.asarray(b, np.float64))
        out[:, k] = column
    return out


def _rotate_fixed(q: jax.Array, vec: np.ndarray) -> jax.Array:
    """float[3]: the constant vector `vec` rotated by the unit wxyz quaternion `q`."""
    vec = jnp.asarray(vec, jnp.float32)
    twice = 2.0 * jnp.cross(q[1:], vec)
    return vec + q[0] * twice + jnp.cross(q[1:], twice)


def _rotate(mat: jax.Array, vec: np.ndarray) -> jax.Array:
    """float[n, 3]: `mat[k] @ vec[k]` for constant vectors (a multiply and a sum, fusible)."""
    return jnp.sum(mat * jnp.asarray(vec, jnp.float32)[:, None, :], axis=-1)


def _compose(mat: jax.Array, fixed: np.ndarray) -> jax.Array:
    """float[n, 3, 3]: `mat[k] @ fixed[k]` for constant matrices."""
    return jnp.sum(mat[..., :, :, None] * jnp.asarray(fixed, jnp.float32)[:, None, :, :], axis=-2)


def quat_to_mat(q: jax.Array) -> jax.Array:
    """float[..., 3, 3] world <- body of unit wxyz quaternions `q: float[..., 4]`."""
    w, x, y, z = (q[..., i] for i in range(4))
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)


class Frames(NamedTuple):
    """World frames of every body (MuJoCo's `xpos`, `xquat` (wxyz), `xmat`) and of every
    joint (`xanchor`, `xaxis`), metres."""

    xpos: jax.Array  # float[nbody, 3]
    xquat: jax.Array  # float[nbody, 4]
    xmat: jax.Array  # float[nbody, 3, 3]
    xanchor: jax.Array  # float[njnt, 3]
    xaxis: jax.Array  # float[njnt, 3]


class ChainKinematics:
    """`fill(data)`: MJX data with MuJoCo's kinematic outputs for a chain of hinge joints.

    Handles what the arm model has: bodies with at most one hinge joint at the body origin,
    geoms and sites; no free/ball/slide joints, no mocap bodies.
    """

    def __init__(self, model: mujoco.MjModel):
        for b in range(1, model.nbody):
            if model.body_jntnum[b] > 1:
                raise ValueError(f"body {b} has {model.body_jntnum[b]} joints; at most 1 supported")
        if model.njnt and (np.any(model.jnt_type != mujoco.mjtJoint.mjJNT_HINGE)
                           or np.any(model.jnt_pos != 0)):
            raise ValueError("ChainKinematics supports hinge joints at their body's origin only")
        if model.nmocap:
            raise ValueError("ChainKinematics does not support mocap bodies")
        self.model = model
        # per body, the linear maps of the parent's quaternion: q -> q * offset (4 rows), and
        # with a joint q -> q * offset * (0, axis) (4 more rows)
        self._quat_maps = [None]
        for b in range(1, model.nbody):
            offset = _right_product(model.body_quat[b])
            if model.body_jntnum[b]:
                axis = model.jnt_axis[model.body_jntadr[b]]
                offset = np.concatenate([offset, _right_product(np.r_[0.0, axis]) @ offset])
            self._quat_maps.append(offset)
        self._ibody_mat = [_quat_to_mat(q) for q in model.body_iquat]
        self._geom_mat = [_quat_to_mat(q) for q in model.geom_quat]
        self._site_mat = [_quat_to_mat(q) for q in model.site_quat]

    def frames(self, qpos: jax.Array) -> Frames:
        """World frames of every body and joint at joint angles `qpos: float[7]` (rad),
        composed as MJX does (so the quaternions' signs are MJX's)."""
        m = self.model
        quat = [jnp.asarray([1.0, 0.0, 0.0, 0.0])]
        pos = [jnp.zeros(3)]
        for b in range(1, m.nbody):
            parent = m.body_parentid[b]
            p = pos[parent] + _rotate_fixed(quat[parent], m.body_pos[b])
            parts = jnp.sum(jnp.asarray(self._quat_maps[b], jnp.float32) * quat[parent], axis=-1)
            if m.body_jntnum[b]:  # q * offset * (cos h, sin h axis): cosine and sine parts
                adr = m.jnt_qposadr[m.body_jntadr[b]]
                half = 0.5 * (qpos[adr] - m.qpos0[adr])
                q = jnp.cos(half) * parts[:4] + jnp.sin(half) * parts[4:]
            else:
                q = parts
            # a barrier per body: without it XLA fuses the whole chain into each consumer and
            # recomputes every parent once per use (the blow-up of MJX's own kinematics here)
            p, q = jax.lax.optimization_barrier((p, q))
            pos.append(p)
            quat.append(q)
        xpos, xquat = jnp.stack(pos), jnp.stack(quat)
        xmat = quat_to_mat(xquat)
        joint_bodies = np.asarray(m.jnt_bodyid)
        # a hinge's axis is fixed in its body (the joint's own rotation leaves it alone)
        xaxis = _rotate(xmat[joint_bodies], m.jnt_axis)
        return Frames(xpos, xquat, xmat, xpos[joint_bodies], xaxis)

    def fill(self, data: mjx.Data) -> mjx.Data:
        """`data` with `xpos, xquat, xmat, xanchor, xaxis, xipos, ximat, geom_xpos, geom_xmat,
        site_xpos, site_xmat` computed at `data.qpos`, as `mjx.kinematics` would."""
        m = self.model
        xpos, xquat, xmat, xanchor, xaxis = self.frames(data.qpos)
        xipos = xpos + _rotate(xmat, m.body_ipos)
        ximat = _compose(xmat, np.stack(self._ibody_mat))
        data = data.replace(xpos=xpos, xquat=xquat, xmat=xmat, xanchor=xanchor, xaxis=xaxis,
                            xipos=xipos, ximat=ximat)

        def attached(body, pos, mat):  # frames fixed on bodies: world positions and rotations
            return xpos[body] + _rotate(xmat[body], pos), _compose(xmat[body], np.stack(mat))

        if m.ngeom:
            geom_xpos, geom_xmat = attached(m.geom_bodyid, m.geom_pos, self._geom_mat)
            data = data.replace(geom_xpos=geom_xpos, geom_xmat=geom_xmat)
        if m.nsite:
            site_xpos, site_xmat = attached(m.site_bodyid, m.site_pos, self._site_mat)
            data = data.replace(site_xpos=site_xpos, site_xmat=site_xmat)
        return data


__all__ = ["ChainKinematics", "Frames", "quat_to_mat"]
