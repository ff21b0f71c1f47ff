"""Zone world pieces without physics: layout sampler, LiDAR, labels, moving zones, alphabet,
config validation. These compile small programs only."""

from __future__ import annotations

import functools
import math
import random

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import specrl_jax
from specrl_jax.envs.zone import ZoneConfig
from specrl_jax.envs.zone.config import level_config
from specrl_jax.envs.zone.labels import alphabet, compute_labels
from specrl_jax.envs.zone.layout import check_feasible, objects, sample_positions
from specrl_jax.envs.zone.sensors import compute_lidar, wall_sensor


# ---- layout -------------------------------------------------------------------------------
@functools.cache
def batched_sampler(config: ZoneConfig):
    parallel = check_feasible(config)
    return jax.jit(jax.vmap(lambda k: sample_positions(k, config, parallel)))


#: layouts per call of `batched_sampler`: under `vmap` its restart loop runs until the slowest
#: layout of the batch is placed, so small batches waste fewer rounds (each layout depends on its
#: key alone: the same layouts either way)
SAMPLE_CHUNK = 8


def sample_many(config: ZoneConfig, num: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    keys, sample = jax.random.split(jax.random.key(seed), num), batched_sampler(config)
    parts = [sample(keys[i:i + SAMPLE_CHUNK]) for i in range(0, num, SAMPLE_CHUNK)]
    return (np.concatenate([np.asarray(xy) for xy, _ in parts]),
            np.concatenate([np.asarray(ok) for _, ok in parts]))


def reference_layout(config: ZoneConfig, rng: random.Random) -> tuple[np.ndarray, int]:
    """The original's sampler, object by object and try by try, in plain Python."""
    keepouts = list(objects(config).keepout)
    for restart in range(config.max_restarts):
        placed: list[tuple[float, float, float]] = []
        for k in keepouts:
            for _ in range(config.max_tries):
                x = rng.uniform(-config.extent + k, config.extent - k)
                y = rng.uniform(-config.extent + k, config.extent - k)
                if all(math.hypot(x - px, y - py) >= pk + k for px, py, pk in placed):
                    placed.append((x, y, k))
                    break
            else:
                break
        else:
            return np.array([(x, y) for x, y, _ in placed]), restart + 1
    raise RuntimeError("no layout")


@pytest.mark.parametrize(
    "config, num, zone_zone, agent_zone, zone_range",
    [
        (level_config("Point", 0), 2000, 1.1, 0.95, 1.95),
        (level_config("Point", 2), 48, 1.4, 1.1, 1.8),  # ~89 restarts each: CPU-costly
        (level_config("Point", 1, overlap=True), 2000, 0.4, 0.6, 2.3),
    ],
    ids=["L0", "L2", "overlap"],
)
def test_layouts_respect_the_original_constraints(config, num, zone_zone, agent_zone, zone_range):
    xy, ok = sample_many(config, num)
    assert ok.all()
    agent, zones = xy[:, 0], xy[:, 1:]
    assert np.abs(agent).max() <= 2.1 + 1e-6
    assert np.abs(zones).max() <= zone_range + 1e-6
    assert np.linalg.norm(zones - agent[:, None], axis=-1).min() >= agent_zone - 1e-5
    pair = np.linalg.norm(zones[:, :, None] - zones[:, None, :], axis=-1)
    pair[:, np.arange(8), np.arange(8)] = np.inf
    assert pair.min() >= zone_zone - 1e-5
    assert np.linalg.norm(zones - agent[:, None], axis=-1).min() > 0.4  # start not in a zone
    # every key gives its own layout
    assert len(np.unique(agent.round(6), axis=0)) == len(agent)


def test_layout_distribution_matches_the_plain_python_sampler():
    # Level 1: about 5 whole-layout restarts per layout, so restarts shape the distribution.
    config = level_config("Point", 1)
    xy, _ = sample_many(config, 1200, seed=1)
    rng = random.Random(1)
    ref = [reference_layout(config, rng) for _ in range(500)]
    ref_xy = np.stack([r[0] for r in ref])
    assert 4.0 < np.mean([r[1] for r in ref]) < 7.0  # the fact sheet measured 5.33

    def features(layouts):
        agent, zones = layouts[:, 0], layouts[:, 1:]
        return {
            "agent_x": agent[:, 0],
            "first_zone_y": zones[:, 0, 1],
            "last_zone_x": zones[:, -1, 0],
            "nearest_zone": np.linalg.norm(zones - agent[:, None], axis=-1).min(axis=1),
            "zone_spread": np.linalg.norm(zones - zones.mean(axis=1, keepdims=True), axis=-1).mean(1),
        }

    ours, theirs = features(xy), features(ref_xy)
    for name in ours:
        assert stats.ks_2samp(ours[name], theirs[name]).pvalue > 1e-3, name


# ---- LiDAR --------------------------------------------------------------------------------
def reference_lidar(agent_pos, agent_mat, zones, colors, num_colors, partial):
    """The original's pseudo-LiDAR formula, zone by zone, in numpy."""
    out = np.zeros((num_colors, 16))
    for p, c in zip(zones, colors):
        v = (np.array([p[0], p[1], 0.0]) - agent_pos) @ agent_mat
        z = complex(v[0], v[1])
        dist, ang = abs(z), np.angle(z) % (2 * np.pi)
        bin_size = 2 * np.pi / 16
        b = int(ang / bin_size)
        sensor = max(0.0, 1.2 - dist) / 1.2 if partial else np.exp(-0.5 * dist)
        obs = out[c]
        obs[b] = max(obs[b], sensor)
        alias = (ang - b * bin_size) / bin_size
        obs[(b + 1) % 16] = max(obs[(b + 1) % 16], alias * sensor)
        obs[(b - 1) % 16] = max(obs[(b - 1) % 16], (1 - alias) * sensor)
    return out


def random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


@pytest.mark.parametrize("partial", [False, True])
def test_lidar_matches_the_original_formula(partial):
    rng = np.random.default_rng(int(partial))
    colors = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    mask = colors[None, :] == np.arange(4)[:, None]
    lidar = jax.jit(lambda *a: compute_lidar(*a, num_bins=16, partial=partial))
    for trial in range(40):
        pos = np.array([*rng.uniform(-2, 2, 2), rng.uniform(0.05, 0.2)])
        # planar yaw for half the trials, full tilt (Car, Ant) for the other half
        mat = random_rotation(rng) if trial % 2 else np.array(
            [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        ) if (a := rng.uniform(0, 2 * np.pi)) is not None else None
        zones = rng.uniform(-2.5, 2.5, (8, 2))
        if trial == 0:  # a zone exactly on a bin border and one straight ahead
            zones[0] = pos[:2] + mat[:2, 0] * 0.7
        ours = lidar(jnp.asarray(pos, jnp.float32), jnp.asarray(mat, jnp.float32),
                     jnp.asarray(zones, jnp.float32), jnp.asarray(mask))
        ref = reference_lidar(pos, mat, zones, colors, 4, partial)
        np.testing.assert_allclose(np.asarray(ours), ref, atol=2e-4)
    if partial:  # zones beyond 1.2 m are invisible
        far = lidar(jnp.zeros(3), jnp.eye(3), jnp.full((8, 2), 1.0), jnp.asarray(mask))
        assert not np.asarray(far).any()


def test_wall_sensor_order_is_east_south_west_north():
    values = np.asarray(wall_sensor(jnp.array([3.3, 0.0]), 3.3))
    np.testing.assert_allclose(values, [1.0, np.exp(-3.3), np.exp(-6.6), np.exp(-3.3)], rtol=1e-5)
    values = np.asarray(wall_sensor(jnp.array([0.0, 3.0]), 3.3))
    np.testing.assert_allclose(values[3], np.exp(-0.3), rtol=1e-5)


# ---- labels and alphabet ------------------------------------------------------------------
def test_labels_use_inclusive_planar_distance_per_colour():
    zones = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.0]])
    radius = jnp.array([0.4, 0.4, 0.4])
    mask = jnp.array([[True, True, False], [False, False, True]])
    assert compute_labels(jnp.array([0.0, 0.4]), zones, radius, mask).tolist() == [True, False]
    assert compute_labels(jnp.array([0.0, 0.41]), zones, radius, mask).tolist() == [False, False]
    assert compute_labels(jnp.array([0.75, 0.0]), zones, radius, mask).tolist() == [True, True]
    assert compute_labels(jnp.array([1.3, 0.0]), zones, radius, mask).tolist() == [True, False]


def test_alphabet_is_none_or_one_unless_zones_can_overlap():
    none_or_one = alphabet(level_config("Point", 0))
    assert none_or_one.shape == (5, 4) and (none_or_one.sum(1) <= 1).all()
    assert alphabet(level_config("Point", 2)).shape == (5, 4)  # discs can at most touch
    for config in (level_config("Point", 0, overlap=True), level_config("Point", 1)):
        subsets = alphabet(config)  # L1 moving zones can come 0.7 m close (< 0.8)
        assert subsets.shape == (16, 4) and len({tuple(r) for r in subsets}) == 16


def test_overlap_layouts_produce_multi_labels():
    config = level_config("Point", 0, overlap=True)
    xy, _ = sample_many(config, 2000)
    zones = xy[:, 1:]
    colors = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    d = np.linalg.norm(zones[:, :, None] - zones[:, None, :], axis=-1)
    different = colors[:, None] != colors[None, :]
    assert ((d < 0.8) & different).any()  # some layouts have overlapping colours


# ---- config validation --------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"robot": "Doggo"}, "unknown robot"),
        ({"colors": ("green", "mauve")}, "distinct names"),
        ({"colors": ("green", "green")}, "distinct names"),
        ({"zones_per_color": 1, "moving_per_color": 2}, "moving_per_color"),
        ({"zones_per_color": (1, 2)}, "one per colour"),
        ({"zone_keepout": 2.6}, "no room"),
        ({"zones_per_color": 6, "zone_keepout": 0.7}, "packed"),
        ({"horizon": 0}, "horizon"),
    ],
)
def test_config_rejects_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ZoneConfig(**kwargs)


def test_unplaceable_layout_is_reported():
    config = ZoneConfig(colors=("red",), zones_per_color=2, zone_keepout=1.8, max_restarts=200)
    with pytest.raises(ValueError, match="cannot place"):
        check_feasible(config)


def test_feasibility_is_judged_once_per_placement_problem(monkeypatch):
    """The Monte Carlo behind `check_feasible` runs once per placement problem (keepouts,
    extent, tries, restarts): a second env of the same config, or one differing elsewhere,
    reuses its rate; another problem is judged anew, and an impossible one raises every time."""
    from specrl_jax.envs.zone import layout
    from specrl_jax.envs.zone.env import ZoneEnv

    calls = []
    estimate = layout.attempt_success_rate

    def counted(*args, **kwargs):
        calls.append(args)
        return estimate(*args, **kwargs)

    monkeypatch.setattr(layout, "attempt_success_rate", counted)
    layout.feasibility_rate.cache_clear()
    config = ZoneConfig(zone_keepout=0.6)
    first = ZoneEnv(config)._num_parallel
    assert ZoneEnv(config)._num_parallel == first
    assert ZoneEnv(ZoneConfig(zone_keepout=0.6, horizon=50, robot="Car"))._num_parallel == first
    assert len(calls) == 1
    fresh = estimate(objects(config).keepout, config.extent, config.max_tries)
    assert layout.feasibility_rate.cache_info().currsize == 1
    assert first == min(layout.MAX_PARALLEL, 2 ** math.ceil(math.log2(math.ceil(2.0 / fresh))))
    check_feasible(ZoneConfig(zone_keepout=0.65))
    assert len(calls) == 2
    impossible = ZoneConfig(colors=("red",), zones_per_color=2, zone_keepout=1.8, max_restarts=200)
    for _ in range(2):
        with pytest.raises(ValueError, match="cannot place"):
            ZoneEnv(impossible)
    assert len(calls) == 4  # its 4000-attempt estimate and the max_restarts retry, once


def test_custom_config_with_sixteen_colours():
    from specrl_jax.envs.zone.config import COLOR_NAMES

    config = ZoneConfig(colors=COLOR_NAMES, zones_per_color=1, zone_keepout=0.45, zone_radius=0.3)
    assert config.propositions == tuple(sorted(COLOR_NAMES)) and config.num_zones == 16
    xy, ok = sample_many(config, 32)
    assert ok.all() and np.abs(xy[:, 1:]).max() <= 2.05 + 1e-6


# ---- moving zones -------------------------------------------------------------------------
def test_moving_zones_run_circles_in_sim_time_with_key_drawn_direction_and_phase():
    from specrl_jax.envs.zone import make_zone
    from specrl_jax.envs.zone.env import ZoneState

    # zone 0 of each colour moves; the kinematic option (the default weld: test_zone_motion.py)
    env, _ = make_zone(level_config("Point", 1, zone_motion="circle"))
    layouts = [env._random_layout(jax.random.key(s), jnp.zeros((9, 2))) for s in range(12)]
    direction = np.stack([np.asarray(l["zone_direction"]) for l in layouts])
    phase = np.stack([np.asarray(l["zone_phase"]) for l in layouts])
    moving = np.array([True, False] * 4)
    assert (np.abs(direction[:, moving]) == 1).all() and (direction[:, ~moving] == 0).all()
    assert {-1.0, 1.0} <= set(direction[:, moving].ravel())
    assert len(np.unique(phase[:, 0])) == 12 and (phase[:, ~moving] == 0).all()

    centre = jnp.asarray(np.random.default_rng(0).uniform(-1.8, 1.8, (8, 2)), jnp.float32)
    zone_direction = jnp.array([1.0, 0, -1.0, 0, 1.0, 0, -1.0, 0])
    zone_phase = jnp.array([0.0, 0, 1.0, 0, 2.0, 0, 3.0, 0])

    def positions(time):
        state = ZoneState(None, None, centre, zone_direction, zone_phase, jnp.int32(time))
        return np.asarray(env.zone_positions(state))

    for time in (0, 1, 25, 999):
        t = time * 0.02  # Point: 10 substeps of 0.002 s per env step
        angle = 2.0 * t * np.asarray(zone_direction) + np.asarray(zone_phase)
        expected = np.asarray(centre) + 0.3 * np.abs(np.asarray(zone_direction))[:, None] * np.stack(
            [np.sin(angle), np.cos(angle)], axis=1
        )
        np.testing.assert_allclose(positions(time), expected, atol=1e-5)
    # direction +1 starting at phase 0 (due +y) moves clockwise: towards +x
    assert positions(1)[0, 0] > centre[0, 0] and positions(0)[0, 1] == pytest.approx(centre[0, 1] + 0.3)
    # the Ant's env step lasts 0.1 s of sim time: its zones move 5x further per step
    ant, _ = make_zone(level_config("Ant", 1))
    assert ant.frame_dt == pytest.approx(5 * env.frame_dt)


def test_make_rejects_overrides_fixed_by_the_id():
    with pytest.raises(ValueError, match="fixed by the env ID"):
        specrl_jax.make("PointLTL0-v0", robot="Car")
    with pytest.raises(ValueError, match="unknown ZoneParams fields"):
        specrl_jax.make("PointLTL0-v0", speed=2.0)
