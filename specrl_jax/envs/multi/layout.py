"""Layout sampling of the multi-agent world, in the original's order, inside `jit`.

The original places the zones (colour by colour), then the agents last. Every object gets up to
`max_tries` uniform tries in `[-extent + k, extent - k]^2` (k its own keepout) and takes the
first that keeps the required distance from every object already placed; if all tries fail the
whole layout restarts (up to `max_restarts` times). Required centre distances, as the original
runs (`reference/zone_env.md` section 11.1): zone-zone the sum of their keepouts; agent-zone the
zone's keepout plus `agent_zone_gap`; agent-agent twice the agent keepout.

Here the tries of one object are drawn `chunk` at a time, the first valid one of the first chunk
that has one taken (the same as trying them one by one), and `num_parallel` whole-layout attempts
run side by side, the first success in attempt order winning: the original's distribution.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.multi.config import MultiZoneConfig

MAX_PARALLEL = 8
CHUNK = 64


class Objects(NamedTuple):
    """Placement table in placement order: zones, then agents.

    Attributes:
        half_range: float32[M], an object's centre is drawn in [-half_range, half_range]^2.
        min_dist: float32[M, M], least centre distance between objects i and j, metres.
    """

    half_range: np.ndarray
    min_dist: np.ndarray


def objects(config: MultiZoneConfig) -> Objects:
    zone_keepout = np.asarray(
        [k for n, k in zip(config.zones_per_color, config.zone_keepout) for _ in range(n)],
        np.float32,
    )
    num_zones, num_agents = zone_keepout.shape[0], config.num_agents
    agent = np.full(num_agents, config.agent_keepout, np.float32)
    min_dist = np.zeros((num_zones + num_agents,) * 2, np.float32)
    min_dist[:num_zones, :num_zones] = zone_keepout[:, None] + zone_keepout[None, :]
    gap = zone_keepout[:, None] + config.agent_zone_gap + np.zeros((1, num_agents), np.float32)
    min_dist[:num_zones, num_zones:] = gap
    min_dist[num_zones:, :num_zones] = gap.T
    min_dist[num_zones:, num_zones:] = agent[:, None] + agent[None, :]
    half_range = config.extent - np.concatenate([zone_keepout, agent])
    return Objects(half_range.astype(np.float32), min_dist)


def _place(key: jax.Array, xy: jax.Array, placed: jax.Array, half: jax.Array, need: jax.Array,
           max_tries: int) -> tuple[jax.Array, jax.Array]:
    """First valid of up to `max_tries` uniform tries, drawn `CHUNK` at a time:
    `(xy float32[2], ok bool[])`."""
    chunk = min(CHUNK, max_tries)
    num_chunks = math.ceil(max_tries / chunk)

    def cond(carry):
        index, _, ok, _ = carry
        return (index < num_chunks) & ~ok

    def body(carry):
        index, _, _, key = carry
        key, key_chunk = jax.random.split(key)
        cand = jax.random.uniform(key_chunk, (chunk, 2), minval=-half, maxval=half)
        dist = jnp.linalg.norm(cand[:, None, :] - xy[None, :, :], axis=-1)  # [T, M]
        valid = jnp.all((dist >= need) | ~placed, axis=1)
        valid &= index * chunk + jnp.arange(chunk) < max_tries
        return index + 1, cand[jnp.argmax(valid)], jnp.any(valid), key

    init = (jnp.array(0), jnp.zeros(2), jnp.array(False), key)
    _, point, ok, _ = jax.lax.while_loop(cond, body, init)
    return point, ok


def _attempt(key: jax.Array, table: Objects, max_tries: int) -> tuple[jax.Array, jax.Array]:
    """One whole-layout attempt: `(xy float32[M, 2], ok bool[])`."""
    half_range, min_dist = jnp.asarray(table.half_range), jnp.asarray(table.min_dist)
    num = half_range.shape[0]

    def place(carry, inputs):
        xy, ok = carry
        index, key_obj = inputs
        point, found = _place(key_obj, xy, jnp.arange(num) < index, half_range[index],
                              min_dist[index], max_tries)
        return (xy.at[index].set(point), ok & found), None

    keys = jax.random.split(key, num)
    (xy, ok), _ = jax.lax.scan(place, (jnp.zeros((num, 2)), jnp.array(True)), (jnp.arange(num), keys))
    return xy, ok


def sample_positions(
    key: jax.Array, config: MultiZoneConfig, num_parallel: int
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Sample zone and agent centres as the original's multi-agent world does.

    Returns:
        `zone_xy float32[Z, 2]`, `agent_xy float32[N, 2]` (metres) and `ok bool[]`, False when
        all `max_restarts` attempts failed (the original raises; the last attempt is returned).
    """
    table = objects(config)
    num_rounds = math.ceil(config.max_restarts / num_parallel)
    attempt = jax.vmap(lambda k: _attempt(k, table, config.max_tries))

    def cond(carry):
        round_, _, ok, _ = carry
        return (round_ < num_rounds) & ~ok

    def body(carry):
        round_, _, _, key = carry
        key, key_round = jax.random.split(key)
        xy, ok = attempt(jax.random.split(key_round, num_parallel))
        first = jnp.argmax(ok)
        return round_ + 1, xy[first], ok[first], key

    init = (jnp.array(0), jnp.zeros((table.half_range.shape[0], 2)), jnp.array(False), key)
    _, xy, ok, _ = jax.lax.while_loop(cond, body, init)
    num_zones = table.half_range.shape[0] - config.num_agents
    return xy[:num_zones], xy[num_zones:], ok


def attempt_success_rate(config: MultiZoneConfig, num_attempts: int = 200, seed: int = 0) -> float:
    """Host-side estimate (numpy) of the chance that one whole-layout attempt succeeds."""
    rng = np.random.default_rng(seed)
    table = objects(config)
    xy = np.zeros((num_attempts, 0, 2))
    ok = np.ones(num_attempts, bool)
    for index, half in enumerate(table.half_range.astype(np.float64)):
        cand = rng.uniform(-half, half, (num_attempts, config.max_tries, 2))
        dist = np.linalg.norm(cand[:, :, None, :] - xy[:, None, :, :], axis=-1)
        valid = np.all(dist >= table.min_dist[index, :index], axis=2)
        ok &= valid.any(axis=1)
        chosen = cand[np.arange(num_attempts), valid.argmax(axis=1)]
        xy = np.concatenate([xy, chosen[:, None, :]], axis=1)
    return float(ok.mean())


def check_feasible(config: MultiZoneConfig) -> int:
    """Raise `ValueError` if the sampler cannot place the objects; return `num_parallel`
    (attempts per loop iteration, sized so that one iteration nearly always succeeds)."""
    rate = attempt_success_rate(config)
    if rate == 0.0:
        rate = max(attempt_success_rate(config, seed=seed) for seed in range(1, 6))
    if rate == 0.0:
        raise ValueError(
            f"cannot place {config.num_agents} agents (keepout {config.agent_keepout}) and "
            f"{sum(config.zones_per_color)} zones (keepouts "
            f"{dict(zip(config.colors, config.zone_keepout))}) inside +-{config.extent} m: no "
            f"success in 2000 whole-layout attempts of {config.max_tries} tries per object; use "
            "fewer agents or zones, or smaller keepouts"
        )
    target = math.ceil(2.0 / rate)
    return int(min(MAX_PARALLEL, 2 ** math.ceil(math.log2(max(target, 1)))))
