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

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

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
    return xy, ok


def attempt_success_rate(config: ZoneConfig, num_attempts: int = 4000, seed: int = 0) -> float:
    """Host-side estimate of the chance that one whole-layout attempt succeeds (numpy)."""
    rng = np.random.default_rng(seed)
    keepout = objects(config).keepout.astype(np.float64)
    xy = np.zeros((num_attempts, 0, 2))
    ok = np.ones(num_attempts, bool)
    for k in keepout:
        cand = rng.uniform(-config.extent + k, config.extent - k, (num_attempts, config.max_tries, 2))
        dist = np.linalg.norm(cand[:, :, None, :] - xy[:, None, :, :], axis=-1)
        valid = np.all(dist >= keepout[None, None, : xy.shape[1]] + k, axis=2)
        ok &= valid.any(axis=1)
        chosen = cand[np.arange(num_attempts), valid.argmax(axis=1)]
        xy = np.concatenate([xy, chosen[:, None, :]], axis=1)
    return float(ok.mean())


def check_feasible(config: ZoneConfig) -> int:
    """Raise `ValueError` if the sampler cannot place the objects; return `num_parallel`.

    `num_parallel` is sized so that one loop iteration nearly always finds a layout, up to
    `MAX_PARALLEL`.
    """
    rate = attempt_success_rate(config)
    if rate == 0.0:
        rate = attempt_success_rate(config, num_attempts=config.max_restarts, seed=1)
    if rate == 0.0:
        raise ValueError(
            f"cannot place the agent and {config.num_zones} zones (keepouts "
            f"{dict(zip(config.colors, config.zone_keepout))}, agent {config.agent_keepout}) inside "
            f"+-{config.extent} m: no success in {config.max_restarts} whole-layout attempts of "
            f"{config.max_tries} tries per object; use fewer zones or smaller keepouts"
        )
    target = math.ceil(2.0 / rate)
    # Capped: a round holds [num_parallel, max_tries, N] distances per env, which at level 2
    # (about 89 attempts per layout) and batch 65,536 would not fit in GPU memory uncapped.
    return int(min(MAX_PARALLEL, 2 ** math.ceil(math.log2(max(target, 1)))))
