"""Sensors: the original's pseudo-LiDAR over zone centres, the wall sensor, robot sensors."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.zone.models import Robot

LIDAR_EXP_GAIN = 0.5
LIDAR_PARTIAL_RANGE = 1.2


def compute_lidar(
    agent_pos: jax.Array,
    agent_mat: jax.Array,
    zone_xy: jax.Array,
    color_mask: jax.Array,
    num_bins: int,
    partial: bool,
) -> jax.Array:
    """Pseudo-LiDAR per colour, aliased to neighbour bins.

    Args:
        agent_pos: float32[3], agent body position, metres.
        agent_mat: float32[3, 3], agent body rotation (world <- body).
        zone_xy: float32[Z, 2], zone centres, metres (z = 0).
        color_mask: bool[P, Z], zone z has colour p.
        num_bins: bins over [0, 2pi), bin 0 starting at the body +x axis, counter-clockwise.
        partial: linear reading `max(0, 1.2 - d) / 1.2` instead of `exp(-0.5 d)`.

    Returns:
        float32[P, num_bins] in [0, 1], the max over each colour's zones.
    """
    offset = jnp.concatenate([zone_xy, jnp.zeros_like(zone_xy[:, :1])], axis=1) - agent_pos
    local = offset @ agent_mat  # row vector times R: the offset in the body frame
    dist = jnp.hypot(local[:, 0], local[:, 1])
    angle = jnp.mod(jnp.arctan2(local[:, 1], local[:, 0]), 2 * jnp.pi)
    bin_size = 2 * jnp.pi / num_bins
    index = jnp.minimum(jnp.floor(angle / bin_size).astype(jnp.int32), num_bins - 1)
    alias = angle / bin_size - index
    if partial:
        reading = jnp.maximum(0.0, LIDAR_PARTIAL_RANGE - dist) / LIDAR_PARTIAL_RANGE
    else:
        reading = jnp.exp(-LIDAR_EXP_GAIN * dist)
    bins = jnp.arange(num_bins)
    per_zone = reading[:, None] * (
        (bins == index[:, None])
        + alias[:, None] * (bins == (index[:, None] + 1) % num_bins)
        + (1 - alias[:, None]) * (bins == (index[:, None] - 1) % num_bins)
    )  # [Z, bins]; the three bins are distinct, so this is the original's max-update per zone
    return jnp.max(jnp.where(color_mask[:, :, None], per_zone[None], 0.0), axis=1, initial=0.0)


def wall_sensor(agent_xy: jax.Array, wall: float) -> jax.Array:
    """float32[4]: `exp(-distance)` to the east, south, west and north walls."""
    x, y = agent_xy[0], agent_xy[1]
    return jnp.exp(-jnp.abs(jnp.stack([x - wall, y + wall, x + wall, y - wall])))


def _quat_to_mat(quat: jax.Array) -> jax.Array:
    w, x, y, z = quat / jnp.linalg.norm(quat)
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    ).reshape(9)


def robot_sensor_reader(model: mujoco.MjModel, robot: Robot) -> Callable[[jax.Array], jax.Array]:
    """A function `sensordata float32[nsensordata] -> float32[E]`, the original's robot sensor
    keys in alphabetical order, each processed as the original does (hinge angles as
    [sin, cos], the ball joint's quaternion as a row-major 3x3 matrix, `agent_pos` z only)."""
    pieces = []
    for key, size in robot.ego_keys:
        sensor = model.sensor(key)
        adr, dim = int(sensor.adr[0]), int(sensor.dim[0])
        kind = int(sensor.type[0])
        if kind == mujoco.mjtSensor.mjSENS_JOINTPOS:
            pieces.append((adr, dim, lambda v: jnp.concatenate([jnp.sin(v), jnp.cos(v)])))
        elif kind == mujoco.mjtSensor.mjSENS_BALLQUAT:
            pieces.append((adr, dim, _quat_to_mat))
        elif kind == mujoco.mjtSensor.mjSENS_FRAMEPOS:
            pieces.append((adr, dim, lambda v: v[2:]))
        else:
            pieces.append((adr, dim, lambda v: v))
    sizes = np.asarray([size for _, size in robot.ego_keys])

    def read(sensordata: jax.Array) -> jax.Array:
        out = jnp.concatenate([f(sensordata[a : a + d]) for a, d, f in pieces])
        return out.reshape(int(sizes.sum()))

    return read
