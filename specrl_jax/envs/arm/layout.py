"""Region layouts: the original's sampler (sequential placement, then the robot keep-out
rejection of the whole layout), exact and inside `jit`; the keep-out is decided by a precomputed
conservative grid where it can be, by the exact hull distance where it cannot.

The original places the regions one by one in colour order, each with up to `max_tries` uniform
tries in the box, accepting the first centre at least `keepout + 2 r` from every region placed
(a region that fails all its tries restarts the layout); then it rejects the whole layout if any
region comes within `keepout` of the robot in its (fixed) neutral pose, and draws again. So a
layout is distributed as a sequential placement conditioned on every centre passing the
keep-out test. Here `layouts_per_round` whole candidate layouts are drawn at once (each the
original's sequential placement) and the first that passes is taken, rounds repeating in a
`lax.while_loop`: the same distribution (`place_round` and `sample_centres` say how tries and
exact tests are rationed without changing it).
"""

from __future__ import annotations

import functools
import pathlib

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
def neutral_obstacles() -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """The robot at its neutral pose in the world frame (computed with MuJoCo C).

    Returns `(hulls, points float32[2, 3])`: the 11 keep-out hulls (a tuple of
    `float32[T_h, 3, 3]` triangles) and the frame-only links' origins, metres.
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
    grasp = data.site_xpos[model.site(arm_model.GRASP_SITE).id]
    points = np.asarray([data.xpos[model.body("link8").id], grasp])
    return tuple(h.astype(np.float32) for h in hulls), points.astype(np.float32)


def keepout_margin(center: jax.Array, config: ArmConfig) -> jax.Array:
    """float[]: how far (m) a region centred at `center: float[3]` is from violating the keep-out:
    the least of its hull distances minus `keepout + r`, and of its distances to the frame-only
    links minus `keepout + r`. Positive passes; 1-Lipschitz in `center`."""
    hulls, points = neutral_obstacles()
    reach = config.keepout + config.region_radius
    dist, _ = geometry.signed_distances(jnp.broadcast_to(center, (len(hulls), 3)),
                                        geometry.hull_set(hulls))
    point_dist = jnp.linalg.norm(jnp.asarray(points) - center, axis=-1)
    return jnp.minimum(jnp.min(dist), jnp.min(point_dist)) - reach


def keepout_ok(center: jax.Array, config: ArmConfig) -> jax.Array:
    """bool[]: a region centred at `center: float[3]` keeps more than `keepout` from every hull
    of the neutral robot (and its centre more than `keepout + r` from the frame-only links)."""
    return keepout_margin(center, config) > 0


#: keep-out grid cell classes
BAD, UNSURE, CLEAR = 0, 1, 2
#: the keep-out grid's coarsest and finest cell edge, metres (a power-of-two ratio)
GRID_COARSE, GRID_FINE = 0.04, 0.01


@functools.cache
def keepout_grid(region_radius: float, keepout: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A conservative classification of the sampling box for the keep-out test.

    Each cell is BAD (every centre in it fails `keepout_ok`), CLEAR (every centre passes) or
    UNSURE, decided from the exact margin at the cell centre: the margin is 1-Lipschitz, so
    it cannot change sign within half a cell diagonal of the centre. Cells start at
    `GRID_COARSE` and only UNSURE ones are split, down to `GRID_FINE`.

    The benchmark's grid (radius 0.06, keep-out 0.08) is stored in `assets/` (written by
    `save_keepout_grid`; computing it takes minutes on a laptop CPU, seconds on a GPU); other
    configs compute theirs on first use.

    Returns `(classes int8[NX, NY, NZ], low float32[3] (the grid's corner, m), cell (m))`.
    """
    stored = _grid_path(region_radius, keepout)
    if stored.exists():
        with np.load(stored) as saved:
            return saved["classes"], saved["low"], float(saved["cell"])
    config = ArmConfig(colors=("magenta",), regions_per_color=1, region_radius=region_radius,
                       keepout=keepout)
    low, high = (np.asarray(x, np.float64) for x in _box(config))
    margin = jax.jit(jax.vmap(lambda c: keepout_margin(c, config)))
    chunk = 4096

    def classify(centres: np.ndarray, cell: float) -> np.ndarray:
        padded = np.zeros((-(-len(centres) // chunk) * chunk, 3), np.float32)
        padded[: len(centres)] = centres
        values = np.concatenate([np.asarray(margin(jnp.asarray(padded[i:i + chunk])))
                                 for i in range(0, len(padded), chunk)])[: len(centres)]
        slack = cell * np.sqrt(3) / 2 + 1e-4  # half diagonal, and float32 rounding
        return np.where(values > slack, CLEAR, np.where(values < -slack, BAD, UNSURE))

    cell = GRID_COARSE
    shape = np.ceil((high - low) / cell).astype(int)
    index = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1)
    classes = classify((low + (index.reshape(-1, 3) + 0.5) * cell), cell).reshape(shape)
    while cell > GRID_FINE * 1.5:
        cell /= 2
        classes = classes.repeat(2, 0).repeat(2, 1).repeat(2, 2)
        unsure = np.argwhere(classes == UNSURE)
        classes[tuple(unsure.T)] = classify(low + (unsure + 0.5) * cell, cell)
    return classes.astype(np.int8), low.astype(np.float32), float(cell)


def _grid_path(region_radius: float, keepout: float) -> pathlib.Path:
    return arm_model.ASSETS / f"keepout_grid_r{region_radius:g}_k{keepout:g}.npz"


def save_keepout_grid(region_radius: float, keepout: float) -> pathlib.Path:
    """Compute the keep-out grid of `(region_radius, keepout)` and store it in `assets/`."""
    path = _grid_path(region_radius, keepout)
    path.unlink(missing_ok=True)
    keepout_grid.cache_clear()
    classes, low, cell = keepout_grid(region_radius, keepout)
    np.savez_compressed(path, classes=classes, low=low, cell=np.float64(cell))
    return path


def grid_class(centres: jax.Array, config: ArmConfig) -> jax.Array:
    """int8[...]: the keep-out grid class (BAD / UNSURE / CLEAR) of `centres: float[..., 3]`."""
    classes, low, cell = keepout_grid(config.region_radius, config.keepout)
    index = jnp.floor((centres - low) / cell).astype(jnp.int32)
    index = jnp.clip(index, 0, jnp.asarray(classes.shape) - 1)
    return jnp.asarray(classes)[index[..., 0], index[..., 1], index[..., 2]]


def _box(config: ArmConfig) -> tuple[jax.Array, jax.Array]:
    r = config.region_radius
    return jnp.array([*BOX_LOW, r]), jnp.array([*BOX_HIGH, r + BOX_HEIGHT])


#: tries drawn for every candidate and region; a candidate with no acceptable one among them
#: draws the rest of its `max_tries` in one of a few shared continuation slots
TRY_BLOCK = 8


def place_round(key: jax.Array, config: ArmConfig, num: int, slots: int
                ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """`num` candidate layouts, each the original's sequential placement, drawn together.

    Region by region, every candidate draws `TRY_BLOCK` uniform tries and takes the first at least
    `keepout + 2 r` from its regions placed so far; the few with no acceptable try draw the
    remaining `max_tries - TRY_BLOCK` in one of `slots` continuation slots, handed out in
    candidate order. A candidate is examined only while the candidates before it used fewer than
    `slots` slots at every region so far (a rule on earlier candidates only), so every examined
    candidate is placed exactly as with all its tries drawn at once. A candidate whose centre
    lands in a BAD keep-out cell is dropped at once (it cannot pass).

    Returns `centres float32[N, Z, 3]`, `alive bool[N]` (placed, no centre in a BAD cell) and
    `examined bool[N]` (a prefix of the candidates).
    """
    low, high = _box(config)
    z = config.num_regions
    sep = config.keepout + 2 * config.region_radius
    block = min(TRY_BLOCK, config.max_tries)
    rest = config.max_tries - block

    def first_acceptable(tries, centres, index):
        """tries float[T, 3], centres float[Z, 3] -> (first acceptable try, any acceptable)."""
        dist = jnp.linalg.norm(tries[:, None, :] - centres[None], axis=-1)  # [T, Z]
        good = jnp.all((dist >= sep) | (jnp.arange(z) >= index), axis=1)
        return tries[jnp.argmax(good)], jnp.any(good)

    def step(carry, inputs):
        centres, alive, examined = carry
        index, key_region = inputs
        key_block, key_rest = jax.random.split(key_region)
        tries = jax.random.uniform(key_block, (num, block, 3), minval=low, maxval=high)
        pick, found = jax.vmap(first_acceptable, in_axes=(0, 0, None))(tries, centres, index)
        if rest > 0:
            need = alive & examined & ~found
            examined = examined & (jnp.cumsum(need) - need < slots)
            (slot,) = jnp.nonzero(need & examined, size=slots, fill_value=num)
            more = jax.random.uniform(key_rest, (slots, rest, 3), minval=low, maxval=high)
            pick_more, found_more = jax.vmap(first_acceptable, in_axes=(0, 0, None))(
                more, centres[jnp.minimum(slot, num - 1)], index)
            pick = pick.at[slot].set(pick_more, mode="drop")
            found = found.at[slot].set(found_more, mode="drop")
        centres = centres.at[:, index].set(pick)
        alive = alive & found & (grid_class(pick, config) != BAD)
        return (centres, alive, examined), None

    init = (jnp.zeros((num, z, 3)), jnp.ones(num, bool), jnp.ones(num, bool))
    keys = jax.random.split(key, z)
    (centres, alive, examined), _ = jax.lax.scan(step, init, (jnp.arange(z), keys))
    return centres, alive, examined


def sample_centres(key: jax.Array, config: ArmConfig) -> tuple[jax.Array, jax.Array]:
    """Region centres as the original draws them: `(float32[Z, 3] metres, ok bool[])`; ok is
    False only if `max_rounds` rounds found nothing (the last candidate is returned).

    Each round draws `layouts_per_round` candidate placements at once (`place_round`). The
    keep-out grid settles most centres; the UNSURE centres of the surviving candidates get the
    exact test, in candidate order, `exact_checks_per_round` at most. A candidate is examined
    only while at least `num_regions` exact tests are left before it (again a rule on earlier
    candidates only), and the round takes the first examined candidate that passes: the first
    valid layout of an i.i.d. sequence, as the original's loop takes it.
    """
    n, budget, z = config.layouts_per_round, config.exact_checks_per_round, config.num_regions
    slots = config.continuation_slots

    def round_(key_round):
        centres, alive, examined = place_round(key_round, config, n, slots)
        unsure = (alive & examined)[:, None] & (grid_class(centres, config) == UNSURE)
        count = jnp.sum(unsure, axis=1)
        examined = examined & (jnp.cumsum(count) - count <= budget - z)
        flat = (unsure & examined[:, None]).reshape(-1)
        (index,) = jnp.nonzero(flat, size=budget, fill_value=n * z)
        tested = jax.vmap(lambda c: keepout_ok(c, config))(
            centres.reshape(-1, 3)[jnp.minimum(index, n * z - 1)])
        passed = jnp.ones(n * z, bool).at[index].set(tested, mode="drop").reshape(n, z)
        valid = alive & examined & jnp.all(passed, axis=1)
        first = jnp.argmax(valid)
        return centres[first], valid[first]

    def cond(carry):
        index, _, ok, _ = carry
        return (index < config.max_rounds) & ~ok

    def body(carry):
        index, _, _, key = carry
        key, key_round = jax.random.split(key)
        centres, ok = round_(key_round)
        return index + 1, centres, ok, key

    init = (jnp.array(0), jnp.zeros((z, 3)), jnp.array(False), key)
    _, centres, ok, _ = jax.lax.while_loop(cond, body, init)
    return centres, ok


#: seeded Monte Carlo points over the sampling box for the build-time feasibility check
FEASIBILITY_POINTS = 512


def _feasibility_points(region_radius: float, keepout: float) -> tuple[ArmConfig, np.ndarray]:
    """A one-region config of that radius and keep-out, and `FEASIBILITY_POINTS` seeded uniform
    centres float32[N, 3] in its sampling box."""
    config = ArmConfig(colors=("magenta",), regions_per_color=1, region_radius=region_radius,
                       keepout=keepout)
    low, high = (np.asarray(x, np.float32) for x in _box(config))
    points = np.random.default_rng(0).uniform(low, high, (FEASIBILITY_POINTS, 3))
    return config, points.astype(np.float32)


@functools.cache
def keepout_pass_fraction(region_radius: float, keepout: float) -> float:
    """The fraction (0..1) of the feasibility points that pass the exact robot keep-out test
    (`keepout_margin`; a compile of about half a second)."""
    config, points = _feasibility_points(region_radius, keepout)
    margin = jax.jit(jax.vmap(lambda c: keepout_margin(c, config)))(jnp.asarray(points))
    return float(np.mean(np.asarray(margin) > 0))


@functools.cache
def grid_clear_fraction(region_radius: float, keepout: float) -> float:
    """A lower bound of `keepout_pass_fraction` from the stored keep-out grid's CLEAR cells (no
    compiling); 0 when no grid is stored."""
    if not _grid_path(region_radius, keepout).exists():
        return 0.0
    _, points = _feasibility_points(region_radius, keepout)
    classes, grid_low, cell = keepout_grid(region_radius, keepout)
    index = np.clip(np.floor((points - grid_low) / cell).astype(int), 0,
                    np.asarray(classes.shape) - 1)
    return float(np.mean(classes[tuple(index.T)] == CLEAR))


def check_feasible(config: ArmConfig) -> None:
    """Raise `ValueError` if the robot keep-out leaves the sampler (almost) no valid layouts.

    With a fraction `p` of the sampling box passing the keep-out, at most about `p ** Z` of
    candidate layouts pass (an optimistic estimate: the original's placement spreads the
    regions apart, into the arm's zone; the benchmark measures 0.2 % against 0.55 ** 8 =
    0.8 %), and a reset draws at most `layouts_per_round * max_rounds` candidates; a config
    expected to find less than one valid layout in that budget is rejected.
    """
    z, capacity = config.num_regions, config.layouts_per_round * config.max_rounds
    r, k = config.region_radius, config.keepout
    if grid_clear_fraction(r, k) ** z * capacity >= 1:
        return
    p = keepout_pass_fraction(r, k)
    if p**z * capacity >= 1:
        return
    raise ValueError(
        f"the robot keep-out leaves too little room for {z} regions: {p:.1%} of the sampling "
        f"box (a Monte Carlo of {FEASIBILITY_POINTS} centres) passes keepout {k} m + "
        f"region_radius {r} m from the neutral arm, so at most about {p:.3g}^{z} = {p**z:.2g} of "
        f"the candidate layouts would pass, and a reset draws at most layouts_per_round x "
        f"max_rounds = {capacity}; accepted: configs with fraction^regions x candidates >= 1 "
        f"(the benchmark's keepout 0.08 m, radius 0.06 m: about 55% of the box passes); use a "
        f"smaller keepout or region_radius, fewer regions, or more layouts_per_round/max_rounds"
    )


def sample_bank(key: jax.Array, config: ArmConfig, num_layouts: int, chunk: int = 256):
    """`num_layouts` exact layouts `(float32[M, Z, 3], ok bool[M])`, `chunk` at a time."""
    chunk = min(chunk, num_layouts)
    num_chunks = -(-num_layouts // chunk)
    keys = jax.random.split(key, num_chunks * chunk).reshape(num_chunks, chunk)
    centres, ok = jax.lax.map(jax.vmap(lambda k: sample_centres(k, config)), keys)
    return centres.reshape(-1, *centres.shape[2:])[:num_layouts], ok.reshape(-1)[:num_layouts]


__all__ = [
    "BAD", "CLEAR", "UNSURE", "check_feasible", "grid_class", "grid_clear_fraction",
    "keepout_grid", "keepout_margin", "keepout_ok", "keepout_pass_fraction", "neutral_obstacles",
    "place_round", "sample_bank", "sample_centres",
]
