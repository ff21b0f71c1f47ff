"""MuJoCo C's contact frame for capsule-plane contacts, for MuJoCo Warp (the Ant's feet).

`contact_frame.py` gives MJX-JAX C's rule (the capsule axis, made orthogonal to the normal, as
first tangent; a fixed direction only for an axis exactly along the normal). MuJoCo Warp 4.0, as
vendored by MJX 3.17, has MJX's rule instead: world y (or z) whenever the projected axis is
shorter than 0.5, i.e. for every capsule within 30 degrees of the normal.

MuJoCo Warp cannot be given a collider for the span of a trace: it builds and launches its
kernels when the compiled program runs, not when JAX traces it. It picks the function for each
pair of geom types from a module-level table (`collision_primitive._PRIMITIVE_COLLISIONS`), read
at every launch, and builds one kernel per list of functions. `install()` puts in that table, for
the rest of the process, a copy of Warp's capsule-plane function whose core is ours: every MuJoCo
Warp model with capsule-plane contacts in the process then makes them as MuJoCo C does (a new
function, so a new kernel: none built before with Warp's frame is reused; a CUDA graph that MJX
captured before `install()` keeps its kernels).
"""

from __future__ import annotations

import threading
import types
from typing import Tuple

import warp as wp

from specrl_jax.envs.zone.contact_frame import MIN_NORM
from specrl_jax.envs.zone.mjx_import import mjx  # noqa: F401  (imports MJX quietly first)

# isort: split
from mujoco.mjx.third_party.mujoco_warp._src.collision_primitive import _PRIMITIVE_COLLISIONS
from mujoco.mjx.third_party.mujoco_warp._src.collision_primitive_core import mat23f, plane_sphere
from mujoco.mjx.third_party.mujoco_warp._src.types import GeomType

#: Below this squared norm a vector counts as zero (`contact_frame.MIN_NORM`, C's `mjMINVAL`).
MIN_NORM_SQUARED = MIN_NORM**2
#: The table entry replaced.
KEY = (GeomType.PLANE, GeomType.CAPSULE)
_LOCK = threading.Lock()


@wp.func
def plane_capsule(
    plane_normal: wp.vec3,
    plane_pos: wp.vec3,
    capsule_pos: wp.vec3,
    capsule_axis: wp.vec3,
    capsule_radius: float,
    capsule_half_length: float,
) -> Tuple[wp.vec2, mat23f, wp.mat33]:
    """Both end-sphere contacts of a capsule against a plane, in Warp's calling convention:
    distances (metres, negative in penetration), positions (one per row, midway between the
    surfaces; +axis end first) and the frame both share (rows: normal, tangent, tangent)."""
    n = plane_normal
    tangent = capsule_axis - n * wp.dot(n, capsule_axis)
    squared = wp.dot(tangent, tangent)
    if squared < MIN_NORM_SQUARED:
        tangent = wp.vec3(1.0, 0.0, 0.0)
    else:
        tangent = tangent / wp.sqrt(squared)
    c = wp.cross(n, tangent)
    frame = wp.mat33(n[0], n[1], n[2], tangent[0], tangent[1], tangent[2], c[0], c[1], c[2])
    segment = capsule_axis * capsule_half_length
    dist1, pos1 = plane_sphere(n, plane_pos, capsule_pos + segment, capsule_radius)
    dist2, pos2 = plane_sphere(n, plane_pos, capsule_pos - segment, capsule_radius)
    pos = mat23f(pos1[0], pos1[1], pos1[2], pos2[0], pos2[1], pos2[2])
    return wp.vec2(dist1, dist2), pos, frame


def _c_frame_wrapper(wrapper: wp.Function) -> wp.Function:
    """Warp's capsule-plane function `wrapper` (its code, unchanged) calling our `plane_capsule`
    instead of Warp's: the same code object over globals where that one name differs."""
    source = wrapper.func
    scope = dict(source.__globals__, plane_capsule=plane_capsule)
    copy = types.FunctionType(source.__code__, scope, source.__name__, source.__defaults__,
                              source.__closure__)
    copy.__module__ = __name__  # its own Warp module: Warp's function stays as it is
    copy.__annotations__ = dict(source.__annotations__)
    copy.__doc__ = source.__doc__
    return wp.func(copy)


def installed() -> bool:
    """Whether MuJoCo Warp makes capsule-plane contacts with C's frame in this process."""
    return getattr(_PRIMITIVE_COLLISIONS.get(KEY), "c_contact_frame", False)


def install() -> None:
    """Make MuJoCo Warp make capsule-plane contacts with MuJoCo C's frame, process-wide.

    Raises:
        RuntimeError: MJX's vendored MuJoCo Warp is not laid out as this module expects.
    """
    with _LOCK:
        if installed():
            return
        wrapper = _PRIMITIVE_COLLISIONS.get(KEY)
        problems = []
        if not isinstance(wrapper, wp.Function):
            problems.append("collision_primitive._PRIMITIVE_COLLISIONS has no Warp function "
                            f"for {KEY}")
        elif "plane_capsule" not in wrapper.func.__code__.co_names:
            problems.append("its capsule-plane function does not call plane_capsule by name")
        elif not isinstance(wrapper.func.__globals__.get("plane_capsule"), wp.Function):
            problems.append("collision_primitive.plane_capsule is not a Warp function")
        if problems:
            raise RuntimeError(
                "MJX's MuJoCo Warp is not laid out as specrl_jax's capsule contact frame expects "
                f"(written for MJX 3.17): {'; '.join(problems)}; update "
                "specrl_jax/envs/zone/warp_contact_frame.py"
            )
        replacement = _c_frame_wrapper(wrapper)
        replacement.c_contact_frame = True
        _PRIMITIVE_COLLISIONS[KEY] = replacement


__all__ = ["install", "installed", "plane_capsule"]
