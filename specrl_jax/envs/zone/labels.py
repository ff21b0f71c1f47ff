"""The labelling function of the Zone worlds and the alphabet it can produce."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.zone.config import ZoneConfig


def compute_labels(
    agent_xy: jax.Array, zone_xy: jax.Array, zone_radius: jax.Array, color_mask: jax.Array
) -> jax.Array:
    """`bool[P]`: colour p holds iff the agent is within (<=) the radius of one of its zones.

    Args:
        agent_xy: float32[2], agent body position, metres.
        zone_xy: float32[Z, 2], current zone centres, metres.
        zone_radius: float32[Z], metres.
        color_mask: bool[P, Z].
    """
    inside = jnp.linalg.norm(zone_xy - agent_xy, axis=-1) <= zone_radius
    return jnp.any(color_mask & inside[None, :], axis=1)


def zones_can_overlap(config: ZoneConfig) -> bool:
    """Whether zones of two different colours can ever share a point.

    Two zone centres are at least the sum of their keepouts apart; a moving zone strays
    `travel` from its centre. Touching discs (distance exactly r1 + r2) share one point only,
    which is treated as no overlap.
    """
    reach = []
    for c, n, m, r, k in zip(
        range(len(config.colors)), config.zones_per_color, config.moving_per_color,
        config.zone_radius, config.zone_keepout,
    ):
        reach += [(c, r, k, config.travel if i < m else 0.0) for i in range(n)]
    for (c1, r1, k1, t1), (c2, r2, k2, t2) in itertools.combinations(reach, 2):
        if c1 != c2 and k1 + k2 - t1 - t2 < r1 + r2 - 1e-9:
            return True
    return False


def alphabet(config: ZoneConfig) -> np.ndarray:
    """`bool[A, P]`: every label the world can produce.

    None-or-one (row 0 nothing, row i proposition i - 1) when zones of different colours
    cannot overlap; every subset (row a = the bits of a) for `.overlap` variants or whenever
    the geometry lets zones of different colours overlap.
    """
    num = len(config.colors)
    if config.overlap_alphabet or zones_can_overlap(config):
        rows = np.arange(2**num)[:, None] >> np.arange(num)[None, :]
        return (rows & 1).astype(bool)
    return np.concatenate([np.zeros((1, num), bool), np.eye(num, dtype=bool)])
