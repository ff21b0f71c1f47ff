"""The arm's contacts with the table and floor: MJX's own colliders, one call per kind of pair.

MJX's collision driver compiles its collider once per distinct mesh (meshes differ in face and
edge counts), so the arm's 13 contact pairs over 6 hulls became 11 copies of the hull colliders,
about 60% of a physics substep's program and of its compile time. Here the hulls' convex data
are padded to one shape and each kind of pair (plane-hull, box-hull) runs once, vmapped over its
pairs; the contacts, their parameters and their order are MJX's. The padding changes no result:
short polygons repeat their last vertex (as MJX pads polygons itself), and the extra faces and
edges repeat the first ones after the real ones, which changes no maximum, minimum or first
arg-max of the separating-axis test. The padding adds arithmetic (every box-hull pair clips
6-cornered polygons, MJX's 4 for half the hulls): 78 ms against MJX's 61 ms for 256 arms on a
2-core CPU; grouping the hulls by polygon size (two calls) gave 71 ms for twice the program.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco.mjx._src import collision_driver
from mujoco.mjx._src.collision_types import FunctionKey
from mujoco.mjx._src.types import ConvexMesh, GeomType

from specrl_jax.envs.zone.mjx_import import mjx


def pad_convex(meshes: list[ConvexMesh]) -> ConvexMesh:
    """One `ConvexMesh` stacking `meshes` (leading axis), padded to the largest counts."""
    verts = {c.vert.shape[0] for c in meshes}
    if len(verts) != 1:
        raise ValueError(f"hulls must share a vertex count (set maxhullvert); got {sorted(verts)}")
    faces = max(c.face.shape[0] for c in meshes)
    corners = max(c.face.shape[1] for c in meshes)
    edges = max(c.edge.shape[0] for c in meshes)

    def pad(c: ConvexMesh) -> ConvexMesh:
        face = np.asarray(c.face)
        face = np.concatenate([face, np.repeat(face[:, -1:], corners - face.shape[1], 1)], 1)
        face_index = np.arange(faces) % face.shape[0]  # the real ones, then repeats
        edge_index = np.arange(edges) % c.edge.shape[0]
        return ConvexMesh(
            vert=np.asarray(c.vert),
            face=face[face_index],
            face_normal=np.asarray(c.face_normal)[face_index],
            edge=np.asarray(c.edge)[edge_index],
            edge_face_normal=np.asarray(c.edge_face_normal)[edge_index],
        )

    return jax.tree.map(lambda *x: jnp.asarray(np.stack(x)), *[pad(c) for c in meshes])


class Collision:
    """`collide(model, data)`: `mjx.collision` for models whose mesh pairs are primitive-hull
    (any number of hulls with one vertex count), each kind of pair run once over its pairs."""

    def __init__(self, mj_model: mujoco.MjModel, model: mjx.Model):
        for name in ("max_geom_pairs", "max_contact_points"):
            if mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_NUMERIC, name) >= 0:
                raise ValueError(f"the arm's collision does not support the {name} numeric")
        groups = collision_driver._geom_groups(mj_model)
        self.keys = list(groups)
        # kinds of pair that hold a mesh second (and a primitive first) run batched
        self.batches = {}
        for key in self.keys:
            first, second = key.types
            if second == GeomType.MESH and first != GeomType.MESH:
                kind = (first, second, key.condim)
                self.batches.setdefault(kind, []).append(key)
        meshes = sorted({key.data_ids[1] for keys in self.batches.values() for key in keys})
        self.slot = {mesh: i for i, mesh in enumerate(meshes)}
        self.meshes = (pad_convex([model._impl.mesh_convex[i] for i in meshes])
                       if meshes else None)
        self.geoms = {key: np.asarray([p[:2] for p in pairs]) for key, pairs in groups.items()}
        self.order = sorted(self.keys, key=lambda k: k.condim)  # stable: MJX's contact order
        self._pair_tables(mj_model, groups)

    def _pair_tables(self, mj_model: mujoco.MjModel, groups: dict) -> None:
        """What `collide_pairs` looks up by contact pair (MuJoCo's `pair` index): its contact
        rows in `collide`'s order, and per kind of pair its geoms and mesh slot (a pair of
        another kind takes the kind's first pair, whose result is then not used)."""
        ncons = {collision_driver._COLLISION_FUNC[k.types].ncon for k in self.keys}
        batched = {k for keys in self.batches.values() for k in keys}
        pair_ids = [p[2] for k in self.keys for p in groups[k]]
        self.ncon_per_pair = ncons.pop() if len(ncons) == 1 else None
        self.supports_pairs = (self.ncon_per_pair is not None and set(self.keys) == batched
                               and sorted(pair_ids) == list(range(mj_model.npair)))
        if not self.supports_pairs:
            return
        rows, start = np.zeros((mj_model.npair, self.ncon_per_pair), np.int32), 0
        for key in self.order:
            for pair in groups[key]:
                rows[pair[2]] = start + np.arange(self.ncon_per_pair)
                start += self.ncon_per_pair
        self.pair_rows = rows
        self.pair_kind = np.zeros(mj_model.npair, np.int32)
        self.kind_geoms, self.kind_slots = [], []
        for index, (kind, keys) in enumerate(self.batches.items()):
            members = [(pair, key) for key in keys for pair in groups[key]]
            geoms = np.tile(np.asarray(members[0][0][:2]), (mj_model.npair, 1))
            slots = np.full(mj_model.npair, self.slot[members[0][1].data_ids[1]])
            for pair, key in members:
                self.pair_kind[pair[2]] = index
                geoms[pair[2]], slots[pair[2]] = pair[:2], self.slot[key.data_ids[1]]
            self.kind_geoms.append(geoms)
            self.kind_slots.append(slots)

    def _one_pair(self, m: mjx.Model, d: mjx.Data, kind: tuple) -> Callable:
        """`(geoms int[2], mesh slot) -> (dist, pos, frame)` of one pair of `kind`."""
        first, second, condim = kind
        func = collision_driver._COLLISION_FUNC[(first, second)]
        slot_key = FunctionKey((first, second), (-1, 0), condim)

        def one(pair: jax.Array, slot: jax.Array):
            mesh = jax.tree.map(lambda x: x[slot], self.meshes)
            m_one = m.tree_replace({"_impl.mesh_convex": (mesh,)})
            return func(m_one, d, slot_key, pair[None])

        return one

    def _batched(self, m: mjx.Model, d: mjx.Data, kind: tuple, keys: list) -> dict:
        """dist, pos, frame of every pair of one kind, split back by MJX group."""
        geoms = np.concatenate([self.geoms[k] for k in keys])
        slots = np.concatenate([[self.slot[k.data_ids[1]]] * len(self.geoms[k]) for k in keys])
        one = self._one_pair(m, d, kind)
        dist, pos, frame = jax.vmap(one)(jnp.asarray(geoms), jnp.asarray(slots))
        out, start = {}, 0
        for key in keys:
            end = start + len(self.geoms[key])
            out[key] = (dist[start:end].reshape(-1), pos[start:end].reshape(-1, 3),
                        frame[start:end].reshape(-1, 3, 3))
            start = end
        return out

    def collide(self, m: mjx.Model, d: mjx.Data) -> mjx.Data:
        """`data` with MJX's contacts (`data._impl.contact`), as `mjx.collision` computes them."""
        if d._impl.ncon == 0:
            return d
        groups = collision_driver._contact_groups(m, d)
        results = {}
        for kind, keys in self.batches.items():
            results.update(self._batched(m, d, kind, keys))
        for key in self.keys:
            if key not in results:
                func = collision_driver._COLLISION_FUNC[key.types]
                results[key] = func(m, d, key, groups[key].geom)
        dist, pos, frame = (jnp.concatenate(x) for x in zip(*(results[k] for k in self.order)))
        contact = self._parameters(groups).replace(dist=dist, pos=pos, frame=frame)
        return d.tree_replace({"_impl.contact": contact})

    def _parameters(self, groups: dict):
        """MJX's contacts in `collide`'s order, without their dist, pos and frame."""
        contacts = []
        for key in self.order:
            contact = groups[key]
            ncon = collision_driver._COLLISION_FUNC[key.types].ncon
            if ncon > 1:
                contact = jax.tree.map(lambda x, r=ncon: jnp.repeat(x, r, axis=0), contact)
            contacts.append(contact)
        return jax.tree.map(lambda *x: jnp.concatenate(x), *contacts)

    def collide_pairs(self, m: mjx.Model, d: mjx.Data, pairs: jax.Array) -> mjx.Data:
        """`data` with the contacts of the contact pairs `pairs` only (int[K], MuJoCo's `pair`
        indices; `ncon_per_pair` contacts each, in that order), as `collide` computes them, and
        the constraint-row count to match: the solve over them is the solve over every contact
        when the other pairs are beyond their margin (their rows are zero)."""
        if not self.supports_pairs:
            raise ValueError("collide_pairs needs every contact pair to be primitive-mesh, one "
                             "contact count per pair, and every pair explicit")
        results = []
        for kind, geoms, slots in zip(self.batches, self.kind_geoms, self.kind_slots):
            one = self._one_pair(m, d, kind)
            results.append(jax.vmap(one)(jnp.asarray(geoms)[pairs], jnp.asarray(slots)[pairs]))
        kind = jnp.asarray(self.pair_kind)[pairs]
        dist, pos, frame = jax.tree.map(
            lambda *r: jnp.select([kind.reshape((-1,) + (1,) * (r[0].ndim - 1)) == i
                                   for i in range(len(r))], r), *results)
        rows = jnp.asarray(self.pair_rows)[pairs].reshape(-1)
        groups = collision_driver._contact_groups(m, d)
        full = d.tree_replace({"_impl.contact": self._parameters(groups)})
        kept = keep_contacts(full, rows)
        contact = kept._impl.contact.replace(dist=dist.reshape(-1), pos=pos.reshape(-1, 3),
                                             frame=frame.reshape(-1, 3, 3))
        return kept.tree_replace({"_impl.contact": contact})


def keep_contacts(data: mjx.Data, rows: jax.Array) -> mjx.Data:
    """`data` with only the contacts `rows` (int[K], of `data._impl.contact`) and its
    constraint-row count to match. The contacts must share one `dim` (their rows are then laid
    out alike); the solve over the kept ones is the solve over all when the others are beyond
    their margin (MJX multiplies their rows by `dist < margin`)."""
    contact, count = data._impl.contact, rows.shape[0]
    if len(set(np.asarray(contact.dim).tolist())) != 1:
        raise ValueError(f"keep_contacts needs one contact dim; got {sorted(set(contact.dim))}")
    fields = ("dist", "pos", "frame", "includemargin", "friction", "solref", "solreffriction",
              "solimp", "geom1", "geom2", "geom")
    contact = contact.replace(**{f: getattr(contact, f)[rows] for f in fields
                                 if getattr(contact, f) is not None},
                              dim=contact.dim[:count], efc_address=contact.efc_address[:count])
    per_contact = (data._impl.nefc - int(contact.efc_address[0])) // data._impl.ncon
    nefc = data._impl.nefc - per_contact * (data._impl.ncon - count)
    return data.tree_replace({"_impl.contact": contact, "_impl.ncon": count, "_impl.nefc": nefc})


class ContactReach:
    """Which arms may have an active constraint row, tested cheaply before MJX's collision.

    A mesh is at least as far from a plane as its nearest hull vertex, and at least as far from
    a box as its vertices lie beyond any one face plane of the box (a separating plane); a pair
    can be within its margin only when that bound is (to `slack`) within it. The vertices are
    the ones MJX's colliders use (`mesh_convex`). Joint-limit rows are active exactly where
    MuJoCo's are (`past_limit`).
    """

    def __init__(self, mj_model: mujoco.MjModel, model: mjx.Model, slack: float = 1e-3):
        m = mj_model
        kinds = {int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_BOX)}
        first, second = m.pair_geom1.copy(), m.pair_geom2.copy()
        swap = m.geom_type[first] == mujoco.mjtGeom.mjGEOM_MESH
        first[swap], second[swap] = second[swap], first[swap]
        if not (set(m.geom_type[first].tolist()) <= kinds
                and np.all(m.geom_type[second] == mujoco.mjtGeom.mjGEOM_MESH)):
            raise ValueError("ContactReach takes plane-mesh and box-mesh contact pairs only")
        if sum(len(pairs) for pairs in collision_driver._geom_groups(m).values()) != m.npair:
            raise ValueError("ContactReach needs every contact in an explicit pair")
        hinge_or_slide = np.isin(m.jnt_type, [mujoco.mjtJoint.mjJNT_HINGE,
                                              mujoco.mjtJoint.mjJNT_SLIDE])
        if m.neq or m.ntendon or np.any(m.dof_frictionloss > 0) or np.any(
                m.jnt_limited.astype(bool) & ~hinge_or_slide):
            raise ValueError("ContactReach knows contact pairs and hinge/slide limits only; this "
                             "model has equality, tendon, friction-loss or ball/free limit rows")
        hulls = [np.asarray(model._impl.mesh_convex[m.geom_dataid[g]].vert) for g in second]
        if len({h.shape for h in hulls}) > 1:
            raise ValueError("ContactReach needs hulls with one vertex count (set maxhullvert)")
        self.mesh_geom, self.other_geom = second, first
        # [P, V, 3], mesh frames
        self.vertices = np.stack(hulls).astype(np.float32) if hulls else np.zeros((0, 1, 3))
        self.is_plane = m.geom_type[first] == mujoco.mjtGeom.mjGEOM_PLANE
        self.half_size = m.geom_size[first].astype(np.float32)
        self.reach = (m.pair_margin + slack).astype(np.float32)  # MJX's includemargin: the margin
        self.limited = m.jnt_limited.astype(bool)
        self.qpos_index = m.jnt_qposadr
        self.jnt_range = m.jnt_range.astype(np.float32)
        self.jnt_margin = m.jnt_margin.astype(np.float32)

    def gaps(self, data: mjx.Data) -> jax.Array:
        """float[P]: per contact pair, a lower bound of the mesh's distance to its plane or box
        (negative: may overlap), m."""
        rot, pos = data.geom_xmat[self.mesh_geom], data.geom_xpos[self.mesh_geom]
        world = pos[:, None, :] + jnp.sum(rot[:, None] * self.vertices[:, :, None, :], -1)
        other_rot, other_pos = data.geom_xmat[self.other_geom], data.geom_xpos[self.other_geom]
        local = jnp.sum(other_rot[:, None] * (world - other_pos[:, None, :])[..., None], -2)
        plane = jnp.min(local[..., 2], axis=1)
        beyond = jnp.concatenate([local - self.half_size[:, None], -local - self.half_size[:, None]],
                                 axis=-1)  # [P, V, 6]: how far each vertex lies past each face
        box = jnp.max(jnp.min(beyond, axis=1), axis=-1)
        return jnp.where(self.is_plane, plane, box)

    def past_limit(self, qpos: jax.Array) -> jax.Array:
        """bool: whether any limited joint has an active limit row (MuJoCo's `pos < 0`)."""
        angle = qpos[self.qpos_index]
        low, high = self.jnt_range[:, 0], self.jnt_range[:, 1]
        pos = jnp.minimum(angle - low, high - angle) - self.jnt_margin
        return jnp.any(self.limited & (pos < 0))


__all__ = ["Collision", "ContactReach", "keep_contacts", "pad_convex"]
