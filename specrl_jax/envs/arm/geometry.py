"""Signed distances from points to convex hulls given as triangles (exact, batched, no loops).

A hull is `float[T, 3, 3]` triangles with outward orientation (counter-clockwise seen from
outside). Outside a hull the distance is the one to the nearest triangle; inside it is minus the
distance to the nearest face plane (exact for a convex solid). Several hulls of different sizes
are measured together as one `HullSet` (their triangles in one flat array), so the program holds
one copy of the distance code, not one per hull.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


def closest_on_triangles(p: jax.Array, tri: jax.Array) -> jax.Array:
    """float[T, 3]: the point of each triangle `tri: float[T, 3, 3]` nearest to `p: float[3]`
    (or to its own point, `p: float[T, 3]`) (Ericson, Real-Time Collision Detection, 5.1.5, written with selects)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    dot = lambda u, v: jnp.sum(u * v, axis=-1)
    d1, d2 = dot(ab, ap), dot(ac, ap)
    bp = p - b
    d3, d4 = dot(ab, bp), dot(ac, bp)
    cp = p - c
    d5, d6 = dot(ab, cp), dot(ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    safe = lambda x: jnp.where(x == 0, 1.0, x)
    # interior of the face
    denom = safe(va + vb + vc)
    v, w = vb / denom, vc / denom
    point = a + ab * v[:, None] + ac * w[:, None]
    # edges
    t_bc = (d4 - d3) / safe((d4 - d3) + (d5 - d6))
    on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    point = jnp.where(on_bc[:, None], b + (c - b) * t_bc[:, None], point)
    t_ac = d2 / safe(d2 - d6)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    point = jnp.where(on_ac[:, None], a + ac * t_ac[:, None], point)
    t_ab = d1 / safe(d1 - d3)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    point = jnp.where(on_ab[:, None], a + ab * t_ab[:, None], point)
    # vertices
    point = jnp.where(((d6 >= 0) & (d5 <= d6))[:, None], c, point)
    point = jnp.where(((d3 >= 0) & (d4 <= d3))[:, None], b, point)
    point = jnp.where(((d1 <= 0) & (d2 <= 0))[:, None], a, point)
    return point


class HullSet(NamedTuple):
    """Hulls of different triangle counts, flattened (static numpy arrays).

    Attributes:
        triangles: float32[T, 3, 3], every hull's triangles, hull after hull.
        normals: float32[T, 3], their outward unit normals.
        owner: int32[T], the hull of each triangle.
        slots: int32[H, Tmax], each hull's triangle indices; short hulls repeat their first
            index after the real ones, which changes no minimum nor first arg-min.
    """

    triangles: np.ndarray
    normals: np.ndarray
    owner: np.ndarray
    slots: np.ndarray


def hull_set(hulls: Sequence[np.ndarray]) -> HullSet:
    """A `HullSet` from per-hull triangles `float[T_h, 3, 3]`."""
    counts = [len(h) for h in hulls]
    starts = np.cumsum([0] + counts[:-1])
    triangles = np.concatenate([np.asarray(h, np.float64) for h in hulls])
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    owner = np.repeat(np.arange(len(hulls)), counts)
    slots = np.stack([s + np.arange(max(counts)) % n for s, n in zip(starts, counts)])
    return HullSet(triangles.astype(np.float32), normals.astype(np.float32),
                   owner.astype(np.int32), slots.astype(np.int32))


def signed_distances(points: jax.Array, hulls: HullSet) -> tuple[jax.Array, jax.Array]:
    """Signed distance from each hull of `hulls` to its own point (negative inside), and the unit
    direction from the hull toward the point (inside: the nearest face's outward normal).

    Args:
        points: float[H, 3], one point per hull, in that hull's frame.
        hulls: the H hulls.

    Returns `(dist float[H], direction float[H, 3])`.
    """
    tri, normals = jnp.asarray(hulls.triangles), jnp.asarray(hulls.normals)
    p = points[hulls.owner]  # [T, 3]: each triangle's point
    gap = p - closest_on_triangles(p, tri)
    dist_sq = jnp.sum(gap * gap, axis=-1)
    height = jnp.sum(normals * (p - tri[:, 0]), axis=-1)
    slots = jnp.asarray(hulls.slots)
    nearest = jnp.take_along_axis(slots, jnp.argmin(dist_sq[slots], axis=1)[:, None], 1)[:, 0]
    face = jnp.take_along_axis(slots, jnp.argmax(height[slots], axis=1)[:, None], 1)[:, 0]
    outside_dist = jnp.sqrt(dist_sq[nearest])
    inside = height[face] <= 0
    out_normal = gap[nearest] / jnp.where(outside_dist > 0, outside_dist, 1.0)[:, None]
    dist = jnp.where(inside, height[face], outside_dist)
    direction = jnp.where((inside | (outside_dist == 0))[:, None], normals[face], out_normal)
    return dist, direction


__all__ = [
    "HullSet", "closest_on_triangles", "hull_set", "signed_distances",
]
