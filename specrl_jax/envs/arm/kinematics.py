"""Forward kinematics of the arm's serial chain, written out body by body.

MJX's generic `kinematics` walks the body tree level by level with gathers and concatenations;
for this 13-body chain XLA turns it into about ten thousand scalar operations (a 1.5 MB HLO
module; 2.7 s for 16 arms on a 2-core CPU, which dominated the whole physics step). Here the
same quantities (MuJoCo's conventions: `xquat` wxyz, `xmat` world <- body) come from a Python
loop over the static chain in which every step is a product with a constant matrix: a body's
quaternion is its parent's times fixed 4 x 4 maps (the body offset, the joint's cosine and sine
parts), and rotations of constant vectors and the frames' 3 x 3 matrices are fixed quadratic
forms of the quaternion. Each product is written as a broadcast multiply and a sum, which XLA
fuses (a `dot` would become a library matrix product per body on a GPU), so a body costs about
twenty array operations.
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


def _rotation_form() -> np.ndarray:
    """float64[3, 3, 4, 4]: `R[i, j] = q' F[i, j] q`, the rotation matrix of a unit wxyz
    quaternion `q` as quadratic forms (the homogeneous formula: no `1 -` terms)."""
    w, x, y, z = range(4)
    form = np.zeros((3, 3, 4, 4))
    squares = {0: (1, 1, -1, -1), 1: (1, -1, 1, -1), 2: (1, -1, -1, 1)}
    for i, signs in squares.items():
        form[i, i] = np.diag(signs)
    products = {  # R[i, j] = 2 (q_a q_b + sign q_c q_d)
        (0, 1): (x, y, -1, w, z), (1, 0): (x, y, 1, w, z),
        (0, 2): (x, z, 1, w, y), (2, 0): (x, z, -1, w, y),
        (1, 2): (y, z, -1, w, x), (2, 1): (y, z, 1, w, x),
    }
    for (i, j), (a, b, sign, c, d) in products.items():
        form[i, j, a, b] = form[i, j, b, a] = 1.0
        form[i, j, c, d] = form[i, j, d, c] = sign
    return form


ROTATION_FORM = _rotation_form()


def _quadratic(form: np.ndarray, outer: jax.Array) -> jax.Array:
    """`q' form[...] q` from `outer = q q'` (float[4, 4]): float[...]."""
    return jnp.sum(jnp.asarray(form, jnp.float32) * outer, axis=(-2, -1))


def _outer(q: jax.Array) -> jax.Array:
    return q[:, None] * q[None, :]


def _rotate(mat: jax.Array, vec: np.ndarray) -> jax.Array:
    """float[n, 3]: `mat[k] @ vec[k]` for constant vectors (a multiply and a sum, fusible)."""
    return jnp.sum(mat * jnp.asarray(vec, jnp.float32)[:, None, :], axis=-1)


def _compose(mat: jax.Array, fixed: np.ndarray) -> jax.Array:
    """float[n, 3, 3]: `mat[k] @ fixed[k]` for constant matrices."""
    return jnp.sum(mat[..., :, :, None] * jnp.asarray(fixed, jnp.float32)[:, None, :, :], axis=-2)


def quat_to_mat(q: jax.Array) -> jax.Array:
    """float[3, 3] world <- body of a unit wxyz quaternion."""
    return _quadratic(ROTATION_FORM, _outer(q))


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
        # per body: the quaternion maps q_parent -> q_parent * offset (4 rows), then with a joint
        # q_parent -> q_parent * offset * (0, axis) (4 more); the offset's world rotation form
        self._quat_maps, self._offset_form = [None], [None]
        for b in range(1, model.nbody):
            offset = _right_product(model.body_quat[b])
            if model.body_jntnum[b]:
                axis = model.jnt_axis[model.body_jntadr[b]]
                offset = np.concatenate([offset, _right_product(np.r_[0.0, axis]) @ offset])
            self._quat_maps.append(offset)
            self._offset_form.append(np.einsum("ijab,j->iab", ROTATION_FORM, model.body_pos[b]))
        self._axis_form = np.einsum("ijab,nj->niab", ROTATION_FORM, model.jnt_axis)
        self._ibody_mat = [_quat_to_mat(q) for q in model.body_iquat]
        self._geom_mat = [_quat_to_mat(q) for q in model.geom_quat]
        self._site_mat = [_quat_to_mat(q) for q in model.site_quat]

    def frames(self, qpos: jax.Array) -> Frames:
        """World frames of every body and joint at joint angles `qpos: float[7]` (rad),
        composed as MJX does (so the quaternions' signs are MJX's)."""
        m = self.model
        quat = [jnp.asarray([1.0, 0.0, 0.0, 0.0])]
        outer = [_outer(quat[0])]
        pos = [jnp.zeros(3)]
        for b in range(1, m.nbody):
            parent = m.body_parentid[b]
            # parent rotation applied to the body offset: a quadratic form of the parent quaternion
            p = pos[parent] + _quadratic(self._offset_form[b], outer[parent])
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
            outer.append(_outer(q))
        outer = jnp.stack(outer)
        xpos = jnp.stack(pos)
        joint_bodies = np.asarray(m.jnt_bodyid)
        # a hinge's axis is fixed in its body, so its world axis is a quadratic form of the body's
        # quaternion after the joint's own rotation too
        xaxis = _quadratic(self._axis_form, outer[joint_bodies][:, None])
        return Frames(xpos, jnp.stack(quat), _quadratic(ROTATION_FORM, outer[:, None, None]),
                      xpos[joint_bodies], xaxis)

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
