"""Zone trainings reset from a bank of exact layouts: each bank row is the exact sampler's draw for
its own key, and a training reset places the robot and the zones as one of the 8 rotations and
reflections of the square of a bank row (`zone/layout.py::from_bank`), at rest."""

import itertools

import jax
import numpy as np

from specrl_jax import families
from specrl_jax.benchmark import experiment
from specrl_jax.envs import make
from specrl_jax.envs.zone import layout as layout_lib


def _symmetries(xy: np.ndarray) -> np.ndarray:
    """float32[8, 1 + Z, 2]: the images of one layout under the square's symmetry group."""
    images = []
    for reflect, turns in itertools.product((False, True), range(4)):
        x, y = (-xy[:, 0] if reflect else xy[:, 0]), xy[:, 1]
        for _ in range(turns):
            x, y = -y, x
        images.append(np.stack([x, y], axis=-1))
    return np.stack(images)


def test_zone_families_train_on_a_bank():
    assert families.ZONE.map_bank_size("gpu") == 65536
    assert families.ZONE.map_bank_size("cpu") == 512


def test_zone_training_resets_draw_exact_layouts_from_the_bank(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))  # the bank is sampled, not read
    world, params = make("PointLTL0-v0")
    key = jax.random.key(5)
    params, method = experiment.with_method("genz", world, params, 6, key)
    bank = np.asarray(params.map_bank)
    assert bank.shape == (6, 1 + world.zone_color.shape[0], 2) and method.env.params is params

    exact = jax.jit(lambda k: layout_lib.sample_positions(k, world.config, world._num_parallel))
    for row, key_row in enumerate(jax.random.split(key, 6)):
        xy, ok = exact(key_row)
        assert bool(ok)
        np.testing.assert_allclose(bank[row], np.asarray(xy), atol=1e-6)

    reset = jax.jit(jax.vmap(method.env.reset, in_axes=(0, None)))
    _, state = reset(jax.random.split(jax.random.key(6), 64), method.init_task_params())
    zone = state.env_state
    placed = np.concatenate([np.asarray(zone.start_qpos)[:, None, :2], np.asarray(zone.zone_xy)],
                            axis=1)
    images = np.stack([_symmetries(row) for row in bank])  # [M, 8, 1 + Z, 2]
    error = np.abs(placed[:, None, None] - images[None]).max(axis=(3, 4))  # [64, M, 8]
    assert (error.min(axis=(1, 2)) < 1e-5).all()  # every reset is an image of a bank row
    rows = error.min(axis=2).argmin(axis=1)
    assert set(rows.tolist()) == set(range(6))  # every layout is drawn
    assert len({tuple(np.unravel_index(e.argmin(), e.shape)) for e in error}) > 12  # and turned
    assert not np.asarray(zone.time).any() and not np.asarray(zone.physics.qvel).any()
