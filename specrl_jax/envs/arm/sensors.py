"""Range-bearing features and labels of the arm (the original's B4/B5 formulas).

Mode 0 measures from the grasp target (a point) to region spheres; mode 1 measures the signed
distance between each observed link's convex hull and each region sphere.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.arm import geometry

PARTIAL_RANGE = 0.25  # metres, the `.partial` variants' linear range


def closeness(dist: jax.Array, partial: bool) -> jax.Array:
    """The original's distance feature: `exp(-2 d)` (full) or `max(0, 0.25 - d) / 0.25`."""
    if partial:
        return jnp.maximum(0.0, PARTIAL_RANGE - dist) / PARTIAL_RANGE
    return jnp.exp(-2.0 * dist)


def point_features(point: jax.Array, centres: jax.Array, radius: jax.Array,
                   color_mask: jax.Array, partial: bool) -> tuple[jax.Array, jax.Array]:
    """Mode 0: features `float32[C, 4]` and labels `bool[C]` per colour.

    Args:
        point: float[3] grasp-target position, metres.
        centres: float[Z, 3] region centres; radius: float[Z] region radii.
        color_mask: bool[C, Z], region z has colour c.
        partial: linear 0.25 m features instead of `exp(-2 m)`.
    """
    ray = centres - point  # [Z, 3]
    length = jnp.linalg.norm(ray, axis=-1)
    nearest = jnp.argmin(jnp.where(color_mask, length[None], jnp.inf), axis=1)  # [C]
    ray_c, length_c, radius_c = ray[nearest], length[nearest], radius[nearest]
    gap = jnp.maximum(0.0, length_c - radius_c)
    unit = ray_c / jnp.where(length_c > 0, length_c, 1.0)[:, None]
    show = (gap > 0) & (gap <= PARTIAL_RANGE) if partial else gap > 0
    features = jnp.concatenate(
        [jnp.where(show[:, None], unit, 0.0), closeness(gap, partial)[:, None]], axis=-1
    )
    inside = jnp.any(color_mask & (length <= radius)[None], axis=1)
    return features.astype(jnp.float32), inside


def link_sphere_distances(link_pos: jax.Array, link_mat: jax.Array,
                          triangles: Sequence[np.ndarray], centres: jax.Array,
                          radius: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Signed link-to-sphere distances `float[L, Z]` (m, negative = penetration) and the unit
    direction `float[L, Z, 3]` from the link's nearest point toward the sphere's centre.

    Args:
        link_pos: float[L, 3], link_mat: float[L, 3, 3] link frames (world <- link).
        triangles: each link's hull in its frame, a sequence of L static float[T_l, 3, 3] (each
            link its own triangle count: no work on padding).
        centres: float[Z, 3]; radius: float[Z].
    """
    hulls = geometry.hull_set(triangles)
    measure = lambda local: geometry.signed_distances(local, hulls)

    def one_region(centre):
        local = jnp.einsum("lj,lji->li", centre - link_pos, link_mat)  # [L, 3], link frames
        dist, normal = measure(local)
        return dist, jnp.einsum("lij,lj->li", link_mat, normal)

    dist, normal = jax.vmap(one_region, out_axes=1)(centres)  # [L, Z], [L, Z, 3]
    return dist - radius, normal


def link_features(dist: jax.Array, normal: jax.Array, color_mask: jax.Array, num_arm: int,
                  partial: bool) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Mode 1: per colour, the nearest region of that colour to each link.

    Args:
        dist: float[L, Z], normal: float[L, Z, 3] from `link_sphere_distances`.
        color_mask: bool[C, Z]; num_arm: the first `num_arm` links are "arm", the rest fingers.

    Returns:
        `features float32[C, L, 4]` (`[dir, f]` per link, dir from the link point to the sphere
        point: it flips when penetrating, as the original's), `arm bool[C]` (any arm link touches
        or penetrates) and `grippers bool[C]` (every finger does).
    """
    masked = jnp.where(color_mask[:, None, :], dist[None], jnp.inf)  # [C, L, Z]
    nearest = jnp.argmin(masked, axis=-1)  # [C, L]
    d = jnp.take_along_axis(masked, nearest[..., None], axis=-1)[..., 0]  # [C, L]
    n = normal[jnp.arange(dist.shape[0])[None, :], nearest]  # [C, L, 3]
    direction = jnp.where((d < 0)[..., None], -n, n)
    f = closeness(d, partial)
    if partial:
        direction = jnp.where((f == 0)[..., None], 0.0, direction)
    features = jnp.concatenate([direction, f[..., None]], axis=-1).astype(jnp.float32)
    touch = d <= 0
    return features, jnp.any(touch[:, :num_arm], axis=1), jnp.all(touch[:, num_arm:], axis=1)


__all__ = ["PARTIAL_RANGE", "closeness", "link_features", "link_sphere_distances", "point_features"]
