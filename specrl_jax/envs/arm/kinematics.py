"""Forward kinematics of the arm's serial chain, written out body by body.

MJX's generic `kinematics` walks the body tree level by level with gathers and concatenations;
for this 13-body chain XLA turns it into about ten thousand scalar operations (a 1.5 MB HLO
module; 2.7 s for 16 arms on a 2-core CPU, which dominated the whole physics step). Here the
same quantities (MuJoCo's conventions: `xquat` wxyz, `xmat` world <- body) come from a Python
loop over the static chain on 3x3 rotation matrices, a few dozen small matrix products.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.zone.mjx_import import mjx


def _quat_to_mat(quat: np.ndarray) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, np.float64))
    return mat.reshape(3, 3)


def _quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    """Hamilton product of wxyz quaternions."""
    w1, x1, y1, z1 = a[0], a[1], a[2], a[3]
    w2, x2, y2, z2 = b[0], b[1], b[2], b[3]
    return jnp.stack([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def quat_to_mat(q: jax.Array) -> jax.Array:
    """float[3, 3] world <- body of a unit wxyz quaternion."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])


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
        self._ibody_mat = [_quat_to_mat(q) for q in model.body_iquat]
        self._geom_mat = [_quat_to_mat(q) for q in model.geom_quat]
        self._site_mat = [_quat_to_mat(q) for q in model.site_quat]

    def frames(self, qpos: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """World frames of every body at joint angles `qpos: float[7]` (rad), composed as MJX
        does (so the quaternions' signs are MJX's).

        Returns `xpos float[nbody, 3]` (m), `xquat float[nbody, 4]` (wxyz), and each joint's
        `xanchor float[njnt, 3]` and `xaxis float[njnt, 3]`.
        """
        m = self.model
        pos = [jnp.zeros(3)]
        quat = [jnp.asarray([1.0, 0.0, 0.0, 0.0])]
        mat = [jnp.eye(3)]
        anchors, axes = [], []
        for b in range(1, m.nbody):
            parent = m.body_parentid[b]
            p = pos[parent] + mat[parent] @ jnp.asarray(m.body_pos[b], jnp.float32)
            q = _quat_mul(quat[parent], jnp.asarray(m.body_quat[b], jnp.float32))
            if m.body_jntnum[b]:
                j = m.body_jntadr[b]
                axis = np.asarray(m.jnt_axis[j], np.float64)
                anchors.append(p)
                axes.append(quat_to_mat(q) @ jnp.asarray(axis, jnp.float32))
                half = 0.5 * (qpos[m.jnt_qposadr[j]] - m.qpos0[m.jnt_qposadr[j]])
                local = jnp.concatenate([jnp.cos(half)[None], jnp.sin(half) * axis])
                q = _quat_mul(q, local)
            # a barrier per body: without it XLA fuses the whole chain into each consumer and
            # recomputes every parent once per use (the blow-up of MJX's own kinematics here)
            p, q = jax.lax.optimization_barrier((p, q))
            pos.append(p)
            quat.append(q)
            mat.append(quat_to_mat(q))
        return jnp.stack(pos), jnp.stack(quat), jnp.stack(anchors), jnp.stack(axes)

    def fill(self, data: mjx.Data) -> mjx.Data:
        """`data` with `xpos, xquat, xmat, xanchor, xaxis, xipos, ximat, geom_xpos, geom_xmat,
        site_xpos, site_xmat` computed at `data.qpos`, as `mjx.kinematics` would."""
        m = self.model
        xpos, xquat, xanchor, xaxis = self.frames(data.qpos)
        xmat = jax.vmap(quat_to_mat)(xquat)
        ipos = jnp.asarray(m.body_ipos, jnp.float32)
        xipos = xpos + jnp.einsum("bij,bj->bi", xmat, ipos)
        inertial = jnp.asarray(np.stack(self._ibody_mat), jnp.float32)
        ximat = jnp.einsum("bij,bjk->bik", xmat, inertial)
        data = data.replace(xpos=xpos, xquat=xquat, xmat=xmat, xanchor=xanchor, xaxis=xaxis,
                            xipos=xipos, ximat=ximat)
        def attached(body, pos, mat):  # frames fixed on bodies: world positions and rotations
            return (xpos[body] + jnp.einsum("nij,nj->ni", xmat[body], jnp.asarray(pos, jnp.float32)),
                    jnp.einsum("nij,njk->nik", xmat[body], jnp.asarray(np.stack(mat), jnp.float32)))

        if m.ngeom:
            geom_xpos, geom_xmat = attached(m.geom_bodyid, m.geom_pos, self._geom_mat)
            data = data.replace(geom_xpos=geom_xpos, geom_xmat=geom_xmat)
        if m.nsite:
            site_xpos, site_xmat = attached(m.site_bodyid, m.site_pos, self._site_mat)
            data = data.replace(site_xpos=site_xpos, site_xmat=site_xmat)
        return data


__all__ = ["ChainKinematics", "quat_to_mat"]
