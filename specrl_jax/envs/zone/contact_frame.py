"""MuJoCo C's contact frame for capsule-plane contacts, for MJX-JAX (the Ant's feet).

A contact's frame is its normal and two tangents. MuJoCo C gives a capsule-plane contact the
capsule axis, made orthogonal to the normal, as first tangent; only an axis exactly along the
normal falls back to a fixed direction (`mju_makeFrame` tests the axis before projecting it).
MJX 3.17's collider falls back to world y whenever the *projected* axis is shorter than 0.5,
i.e. for every capsule within 30 degrees of the normal, which is how the Ant stands on its foot
tips (~10 degrees). The original's pyramidal friction cone is not rotation-invariant, so the
rotated frame changes the contact forces (docs/fidelity.md; benchmarks/zone_contact_diff.py in
git history).

MJX picks colliders from a module-level table, `collision_driver._COLLISION_FUNC`, and reads it
only while JAX traces `collision_driver.collision` (no MJX function on that path is cached by
`jax.jit`); the number of contacts per pair (`ncon`) is read from the same table when MJX sizes
its data, and ours equals MJX's. `c_contact_frame()` puts `plane_capsule` in that table for the
duration of a `with` block, so only what is traced inside it (`Physics`, for models with
capsule-floor pairs) sees it; other MJX users in the process keep MJX's collider outside the
block. Two caveats: the table is process-global, so another thread tracing MJX during the block
would see ours; and `jax.jit` reuses a trace it made outside the block (e.g. of `mjx.forward`
itself), so the block must be around the tracing of a function of its own (`Physics` traces
fresh closures).
"""

from __future__ import annotations

import contextlib
import inspect
import threading
from collections.abc import Iterator

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.zone.mjx_import import mjx  # noqa: F401  (imports MJX quietly first)

# isort: split
from mujoco.mjx._src import collision_driver, collision_primitive
from mujoco.mjx._src.types import GeomType

#: The table entry replaced, and the number of contacts MJX makes per capsule-plane pair.
KEY = (GeomType.PLANE, GeomType.CAPSULE)
NCON = 2
#: MuJoCo C's `mjMINVAL`: below this norm a vector counts as zero.
MIN_NORM = 1e-15
_LOCK = threading.RLock()


def _plane_capsule_one(
    plane_pos: jax.Array, plane_mat: jax.Array, cap_pos: jax.Array, cap_mat: jax.Array,
    cap_size: jax.Array,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Both end-sphere contacts of one capsule against one plane.

    Returns:
        dist [2] (metres, negative in penetration), pos [2, 3] (midway between the surfaces),
        frame [2, 3, 3] (rows: normal, first tangent, second tangent), for the ends at
        +axis and -axis in that order (MuJoCo C's and MJX's order).
    """
    normal, axis = plane_mat[:, 2], cap_mat[:, 2]
    radius, half_length = cap_size[0], cap_size[1]
    tangent = axis - normal * jnp.dot(normal, axis)
    squared = jnp.dot(tangent, tangent)
    degenerate = squared < MIN_NORM**2
    # the square root only of a safe value, so that gradients stay finite at an upright capsule
    norm = jnp.sqrt(jnp.where(degenerate, 1.0, squared))
    tangent = jnp.where(degenerate, jnp.array([1.0, 0.0, 0.0], tangent.dtype), tangent / norm)
    frame = jnp.stack([normal, tangent, jnp.cross(normal, tangent)])
    ends = cap_pos + jnp.stack([axis, -axis]) * half_length
    dist = (ends - plane_pos) @ normal - radius
    pos = ends - normal * (radius + 0.5 * dist)[:, None]
    return dist, pos, jnp.stack([frame, frame])


def plane_capsule(m, d, key, geom: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """MJX collider (MJX's calling convention) for G plane-capsule pairs with C's frame.

    Args:
        m, d: the MJX model and data (geom poses from `d`, sizes from `m`).
        key: MJX's grouping key (unused).
        geom: int[G, 2], (plane, capsule) geom ids.

    Returns:
        dist [2G], pos [2G, 3], frame [2G, 3, 3]: two contacts per pair, pair-major.
    """
    del key
    plane, cap = geom[:, 0], geom[:, 1]
    dist, pos, frame = jax.vmap(_plane_capsule_one)(
        d.geom_xpos[plane], d.geom_xmat[plane], d.geom_xpos[cap], d.geom_xmat[cap],
        m.geom_size[cap],
    )
    return dist.reshape(-1), pos.reshape(-1, 3), frame.reshape(-1, 3, 3)


plane_capsule.ncon = NCON


def check_mjx() -> None:
    """Raise RuntimeError unless MJX's collider table is the one `c_contact_frame` expects:
    a dict read by `collision_driver.collision`, whose capsule-plane entry is MJX's own
    collider taking (m, d, key, geom) and making `NCON` contacts per pair (or ours, inside
    a `c_contact_frame` block)."""
    version = getattr(mujoco, "__version__", "?")
    table = getattr(collision_driver, "_COLLISION_FUNC", None)
    problems = []
    if not isinstance(table, dict):
        problems.append("collision_driver._COLLISION_FUNC is missing or not a dict")
    else:
        entry = table.get(KEY)
        if entry is None:
            problems.append(f"the table has no {KEY} entry")
        elif entry is plane_capsule:
            pass  # a `c_contact_frame` block is open
        elif entry is not getattr(collision_primitive, "plane_capsule", None):
            problems.append(f"its {KEY} entry is {entry!r}, not collision_primitive.plane_capsule")
        else:
            if getattr(entry, "ncon", None) != NCON:
                problems.append(f"its ncon is {getattr(entry, 'ncon', None)!r}, expected {NCON}")
            if len(inspect.signature(entry).parameters) != 4:
                problems.append(f"its signature is {inspect.signature(entry)}, "
                                "expected (m, d, key, geom)")
    collide = getattr(collision_driver, "collision", None)
    if collide is None or "_COLLISION_FUNC" not in collide.__code__.co_names:
        problems.append("collision_driver.collision does not read _COLLISION_FUNC")
    if problems:
        raise RuntimeError(
            f"MuJoCo MJX {version} is not laid out as specrl_jax's capsule contact frame "
            f"expects (written for MJX 3.17): {'; '.join(problems)}. The Ant's physics would "
            "silently use MJX's contact frame; update specrl_jax/envs/zone/contact_frame.py"
        )


def plane_capsule_pairs(model: mujoco.MjModel) -> int:
    """Number of plane-capsule geom pairs of `model` that can collide (contype/conaffinity
    filter, explicit pairs; no bodies or exclusions considered, an upper bound)."""
    plane = np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)
    capsule = np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_CAPSULE)
    contype, conaffinity = model.geom_contype, model.geom_conaffinity
    count = sum(
        bool((contype[p] & conaffinity[c]) | (contype[c] & conaffinity[p]))
        for p in plane for c in capsule
    )
    types = {int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_CAPSULE)}
    count += sum(
        {int(model.geom_type[g]) for g in pair} == types
        for pair in zip(model.pair_geom1, model.pair_geom2)
    )
    return int(count)


@contextlib.contextmanager
def c_contact_frame() -> Iterator[None]:
    """Within the block, MJX-JAX traces capsule-plane contacts with MuJoCo C's frame; MJX's
    collider is restored on exit (also on error). Re-entrant."""
    check_mjx()
    with _LOCK:
        previous = collision_driver._COLLISION_FUNC[KEY]
        collision_driver._COLLISION_FUNC[KEY] = plane_capsule
        try:
            yield
        finally:
            collision_driver._COLLISION_FUNC[KEY] = previous


__all__ = ["c_contact_frame", "check_mjx", "plane_capsule", "plane_capsule_pairs"]
