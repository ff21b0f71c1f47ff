"""Region layouts: the original's sampler (sequential placement, then the robot keep-out
rejection of the whole layout), exact and inside `jit`.

The original places the regions one by one in colour order, each with up to `max_tries` uniform
tries in the box, accepting the first centre at least `keepout + 2 r` from every region placed
(a region that fails all its tries restarts the layout); then it rejects the whole layout if any
region comes within `keepout` of the robot in its (fixed) neutral pose, and draws again. So a
layout is distributed as a sequential placement conditioned on every centre passing the
keep-out test. Here `layouts_per_round` whole candidate layouts are drawn at once (each the
original's sequential placement, its tries drawn together and the first acceptable taken) and
the first that passes is taken, rounds repeating in a `lax.while_loop`: the same distribution.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.arm import geometry
from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.config import BOX_HEIGHT, BOX_HIGH, BOX_LOW, ArmConfig

#: the hulls of the keep-out check (the original's links -1, 0..6, 8, 9, 10) and the frame-only
#: links checked by centre distance (panda_link8 and the grasp target)
KEEPOUT_HULLS = (("link0", "link0", 0.0),) + tuple(
    (body, hull, angle) for body, (hull, angle) in zip(arm_model.LINK_BODIES, arm_model.LINK_HULLS)
)


@functools.cache
def neutral_obstacles() -> tuple[np.ndarray, np.ndarray]:
    """The robot at its neutral pose in the world frame (computed with MuJoCo C).

    Returns `(triangles float32[H, T, 3, 3], points float32[2, 3])`: the 11 keep-out hulls
    (padded by repeating a triangle) and the frame-only links' origins, metres.
    """
    model = arm_model.load_model()
    data = mujoco.MjData(model)
    data.qpos[:] = arm_model.NEUTRAL_QPOS
    mujoco.mj_kinematics(model, data)
    hulls = []
    for body, name, angle in KEEPOUT_HULLS:
        vertices, faces = arm_model.read_hull(name)
        local = arm_model._yaw(vertices, angle)
        b = model.body(body).id
        hulls.append((local @ data.xmat[b].reshape(3, 3).T + data.xpos[b])[faces])
    most = max(h.shape[0] for h in hulls)
    tris = np.asarray([np.concatenate([h, np.repeat(h[:1], most - len(h), 0)]) for h in hulls])
    grasp = data.site_xpos[model.site(arm_model.GRASP_SITE).id]
    points = np.asarray([data.xpos[model.body("link8").id], grasp])
    return tris.astype(np.float32), points.astype(np.float32)


def keepout_ok(center: jax.Array, config: ArmConfig) -> jax.Array:
    """bool[]: a region centred at `center: float[3]` keeps more than `keepout` from every hull
    of the neutral robot (and its centre more than `keepout + r` from the frame-only links)."""
    tris, points = neutral_obstacles()
    reach = config.keepout + config.region_radius
    # one hull at a time: under vmapped resets the per-triangle work is the memory peak
    dist = jax.lax.map(lambda tri: geometry.signed_distance(center, tri)[0], jnp.asarray(tris))
    point_dist = jnp.linalg.norm(jnp.asarray(points) - center, axis=-1)
    return jnp.all(dist > reach) & jnp.all(point_dist > reach)


def _box(config: ArmConfig) -> tuple[jax.Array, jax.Array]:
    r = config.region_radius
    return jnp.array([*BOX_LOW, r]), jnp.array([*BOX_HIGH, r + BOX_HEIGHT])


def place(key: jax.Array, config: ArmConfig) -> tuple[jax.Array, jax.Array]:
    """One sequential placement: `(centres float32[Z, 3], ok bool[])` (ok False when a region
    failed all its tries)."""
    low, high = _box(config)
    num = config.num_regions
    sep = config.keepout + 2 * config.region_radius

    def step(carry, inputs):
        centres, ok = carry
        index, key_region = inputs
        cand = jax.random.uniform(key_region, (config.max_tries, 3), minval=low, maxval=high)
        dist = jnp.linalg.norm(cand[:, None, :] - centres[None], axis=-1)  # [T, Z]
        placed = jnp.arange(num) < index
        good = jnp.all((dist >= sep) | ~placed, axis=1)
        centres = centres.at[index].set(cand[jnp.argmax(good)])
        return (centres, ok & jnp.any(good)), None

    keys = jax.random.split(key, num)
    init = (jnp.zeros((num, 3)), jnp.array(True))
    (centres, ok), _ = jax.lax.scan(step, init, (jnp.arange(num), keys))
    return centres, ok


def attempt(key: jax.Array, config: ArmConfig) -> tuple[jax.Array, jax.Array]:
    """One whole layout through both of the original's tests: `(centres [Z, 3], ok bool[])`."""
    centres, placed = place(key, config)
    clear = jax.vmap(lambda c: keepout_ok(c, config))(centres)
    return centres, placed & jnp.all(clear)


def sample_centres(key: jax.Array, config: ArmConfig) -> tuple[jax.Array, jax.Array]:
    """Region centres as the original draws them: `(float32[Z, 3] metres, ok bool[])`; ok is
    False only if `max_rounds` rounds found nothing (the last candidate is returned)."""
    n = config.layouts_per_round

    def round_(key_round):
        centres, ok = jax.lax.map(
            lambda k: attempt(k, config), jax.random.split(key_round, n), batch_size=min(n, 8)
        )
        first = jnp.argmax(ok)
        return centres[first], ok[first]

    def cond(carry):
        index, _, ok, _ = carry
        return (index < config.max_rounds) & ~ok

    def body(carry):
        index, _, _, key = carry
        key, key_round = jax.random.split(key)
        centres, ok = round_(key_round)
        return index + 1, centres, ok, key

    init = (jnp.array(0), jnp.zeros((config.num_regions, 3)), jnp.array(False), key)
    _, centres, ok, _ = jax.lax.while_loop(cond, body, init)
    return centres, ok


def sample_bank(key: jax.Array, config: ArmConfig, num_layouts: int, chunk: int = 256):
    """`num_layouts` exact layouts `(float32[M, Z, 3], ok bool[M])`, `chunk` at a time."""
    chunk = min(chunk, num_layouts)
    num_chunks = -(-num_layouts // chunk)
    keys = jax.random.split(key, num_chunks * chunk).reshape(num_chunks, chunk)
    centres, ok = jax.lax.map(jax.vmap(lambda k: sample_centres(k, config)), keys)
    return centres.reshape(-1, *centres.shape[2:])[:num_layouts], ok.reshape(-1)[:num_layouts]


__all__ = ["attempt", "keepout_ok", "neutral_obstacles", "place", "sample_bank", "sample_centres"]
