"""Layout sampling: the original's sequential rejection sampler, run inside `jit`.

The original places the agent, then every zone in colour order; each object gets up to
`max_tries` uniform tries in `[-extent + k, extent - k]^2` (k its own keepout) and is accepted
when it is at least `k + k_o` from every object o already placed; when an object fails all its
tries the whole layout restarts (up to `max_restarts` times).

Here the tries of one object are drawn at once and the first acceptable one is taken, and
`num_parallel` whole-layout attempts run side by side per loop iteration, the first success in
attempt order winning. Both are the same distribution as the one-by-one original.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.base import sampler_check
from specrl_jax.envs.zone.config import ZoneConfig

MAX_PARALLEL = 16


class Objects(NamedTuple):
    """Placement table, agent first. `keepout: float32[N]`, metres."""

    keepout: np.ndarray


def objects(config: ZoneConfig) -> Objects:
    zone_keepouts = [k for n, k in zip(config.zones_per_color, config.zone_keepout) for _ in range(n)]
    return Objects(np.asarray([config.agent_keepout, *zone_keepouts], np.float32))


def _attempt(key: jax.Array, keepout: jax.Array, extent: float, tries: int) -> tuple[jax.Array, jax.Array]:
    """One whole-layout attempt: `(xy float32[N, 2], ok bool[])`."""
    num = keepout.shape[0]

    def place(carry, inputs):
        xy, ok = carry
        index, key_obj = inputs
        k = keepout[index]
        cand = jax.random.uniform(key_obj, (tries, 2), minval=-extent + k, maxval=extent - k)
        dist = jnp.linalg.norm(cand[:, None, :] - xy[None, :, :], axis=-1)  # [T, N]
        placed = jnp.arange(num) < index
        valid = jnp.all((dist >= keepout + k) | ~placed, axis=1)
        xy = xy.at[index].set(cand[jnp.argmax(valid)])
        return (xy, ok & jnp.any(valid)), None

    keys = jax.random.split(key, num)
    (xy, ok), _ = jax.lax.scan(
        place, (jnp.zeros((num, 2)), jnp.array(True)), (jnp.arange(num), keys)
    )
    return xy, ok


def sample_positions(
    key: jax.Array, config: ZoneConfig, num_parallel: int
) -> tuple[jax.Array, jax.Array]:
    """Sample agent and zone centres as the original does.

    Args:
        key: PRNG key.
        config: the world's config.
        num_parallel: whole-layout attempts per loop iteration (a speed knob only).

    Returns:
        `xy: float32[1 + Z, 2]` (metres; row 0 the agent, then zones in placement order) and
        `ok: bool[]`, False when every one of `max_restarts` attempts failed (the original
        raises then; the last attempt is returned).
    """
    keepout = jnp.asarray(objects(config).keepout)
    num_rounds = math.ceil(config.max_restarts / num_parallel)
    attempt = jax.vmap(lambda k: _attempt(k, keepout, config.extent, config.max_tries))

    def cond(carry):
        round_, _, ok, _ = carry
        return (round_ < num_rounds) & ~ok

    def body(carry):
        round_, _, _, key = carry
        key, key_round = jax.random.split(key)
        xy, ok = attempt(jax.random.split(key_round, num_parallel))
        first = jnp.argmax(ok)
        return round_ + 1, xy[first], ok[first], key

    init = (jnp.array(0), jnp.zeros((keepout.shape[0], 2)), jnp.array(False), key)
    _, xy, ok, _ = jax.lax.while_loop(cond, body, init)
    sampler_check(
        ok, f"no layout of the agent and {config.num_zones} zones in max_restarts="
        f"{config.max_restarts} attempts; use fewer or smaller zones"
    )
    return xy, ok


def attempt_success_rate(
    keepout: np.ndarray, extent: float, max_tries: int, num_attempts: int = 4000, seed: int = 0
) -> float:
    """Host-side estimate of the chance that one whole-layout attempt succeeds (numpy), for
    the placement table `keepout: [N]` (metres, agent first; `objects`)."""
    rng = np.random.default_rng(seed)
    keepout = np.asarray(keepout, np.float64)
    xy = np.zeros((num_attempts, 0, 2))
    ok = np.ones(num_attempts, bool)
    for k in keepout:
        cand = rng.uniform(-extent + k, extent - k, (num_attempts, max_tries, 2))
        dist = np.linalg.norm(cand[:, :, None, :] - xy[:, None, :, :], axis=-1)
        valid = np.all(dist >= keepout[None, None, : xy.shape[1]] + k, axis=2)
        ok &= valid.any(axis=1)
        chosen = cand[np.arange(num_attempts), valid.argmax(axis=1)]
        xy = np.concatenate([xy, chosen[:, None, :]], axis=1)
    return float(ok.mean())


@functools.lru_cache(maxsize=None)
def feasibility_rate(
    keepout: tuple[float, ...], extent: float, max_tries: int, max_restarts: int
) -> float:
    """The success rate `check_feasible` judges, computed once per placement problem (the
    fields of a config that fix it; a Monte Carlo of about a second, seeded, so the same)."""
    rate = attempt_success_rate(keepout, extent, max_tries)
    if rate == 0.0:
        rate = attempt_success_rate(keepout, extent, max_tries, num_attempts=max_restarts, seed=1)
    return rate


def check_feasible(config: ZoneConfig) -> int:
    """Raise `ValueError` if the sampler cannot place the objects; return `num_parallel`.

    `num_parallel` is sized so that one loop iteration nearly always finds a layout, up to
    `MAX_PARALLEL`.
    """
    rate = feasibility_rate(
        tuple(objects(config).keepout.tolist()), config.extent, config.max_tries,
        config.max_restarts,
    )
    if rate == 0.0:
        raise ValueError(
            f"cannot place the agent and {config.num_zones} zones (keepouts "
            f"{dict(zip(config.colors, config.zone_keepout))}, agent {config.agent_keepout}) inside "
            f"+-{config.extent} m: no success in {config.max_restarts} whole-layout attempts of "
            f"{config.max_tries} tries per object; use fewer zones or smaller keepouts"
        )
    # The sampler gives up after max_restarts attempts (returning overlapping zones, flagged
    # only in checked mode), so demand that giving up be rarer than exp(-20) per reset.
    if rate * config.max_restarts < 20:
        raise ValueError(
            f"layouts of the agent and {config.num_zones} zones (keepouts "
            f"{dict(zip(config.colors, config.zone_keepout))}, agent {config.agent_keepout}) inside "
            f"+-{config.extent} m are too rare: about {rate:.2g} of whole-layout attempts succeed, "
            f"and a reset must succeed within max_restarts={config.max_restarts} attempts with "
            f"near certainty (rate x max_restarts >= 20); use fewer zones, smaller keepouts or "
            "a larger max_restarts"
        )
    target = math.ceil(2.0 / rate)
    # Capped: a round holds [num_parallel, max_tries, N] distances per env, which at level 2
    # (about 89 attempts per layout) and batch 65,536 would not fit in GPU memory uncapped.
    return int(min(MAX_PARALLEL, 2 ** math.ceil(math.log2(max(target, 1)))))


# ------------------------------------------------------------ layout bank (opt-in fast resets)


def sample_bank(
    key: jax.Array, config: ZoneConfig, num_parallel: int, num_layouts: int, chunk: int = 4096
) -> tuple[jax.Array, jax.Array]:
    """`num_layouts` exact layouts: `(xy float32[M, 1 + Z, 2], ok bool[M])`, drawn `chunk` at
    a time (a chunk holds [chunk, num_parallel, max_tries, 1 + Z] distances per round)."""
    chunk = min(chunk, num_layouts)
    num_chunks = -(-num_layouts // chunk)
    sample = jax.vmap(lambda k: sample_positions(k, config, num_parallel))
    keys = jax.random.split(key, num_chunks * chunk).reshape(num_chunks, chunk)
    xy, ok = jax.lax.map(sample, keys)
    return xy.reshape(-1, *xy.shape[2:])[:num_layouts], ok.reshape(-1)[:num_layouts]


def from_bank(key: jax.Array, bank: jax.Array) -> jax.Array:
    """A bank entry under a symmetry of the square: `float32[1 + Z, 2]`.

    Uniform entry, then one of the 8 rotations and reflections about the origin, uniformly:
    the placement squares and the distance rules are invariant under them, so each image of
    an exact layout is as likely as the layout itself.
    """
    key_entry, key_symmetry = jax.random.split(key)
    xy = jnp.asarray(bank)[jax.random.randint(key_entry, (), 0, bank.shape[0])]
    symmetry = jax.random.randint(key_symmetry, (), 0, 8)
    quarter_turns, reflect = symmetry % 4, symmetry >= 4
    x = jnp.where(reflect, -xy[:, 0], xy[:, 0])
    y = xy[:, 1]
    for turn in range(1, 4):  # rotate by 90 degrees `quarter_turns` times: (x, y) -> (-y, x)
        rotated = quarter_turns >= turn
        x, y = jnp.where(rotated, -y, x), jnp.where(rotated, x, y)
    return jnp.stack([x, y], axis=-1)
