"""The disk cache of reset banks: a second identical request reads the sampled bank back."""

import jax
import numpy as np
import pytest

from specrl_jax.envs import bank_cache
from specrl_jax.envs.letter import LetterConfig, LetterWorld


@pytest.fixture
def world():
    return LetterWorld(LetterConfig(grid_size=5, letters=("a", "b"), counts=2))


def test_a_stored_bank_is_read_back_bit_for_bit(world, monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    key = jax.random.key(4)
    sampled = bank_cache.with_map_bank(world, world.default_params, key, 16)
    assert len(list((tmp_path / "banks").glob("*.npz"))) == 1

    def no_sampling(*args, **kwargs):
        raise AssertionError("the bank was sampled again")

    monkeypatch.setattr(LetterWorld, "with_map_bank", no_sampling)
    read = bank_cache.with_map_bank(world, world.default_params, key, 16)
    np.testing.assert_array_equal(np.asarray(read.map_bank), np.asarray(sampled.map_bank))
    assert read.map_bank.dtype == sampled.map_bank.dtype and read.map_bank.shape == (16, 5, 5)


def test_other_keys_sizes_and_configs_name_other_banks(world):
    key = jax.random.key(4)
    names = {
        bank_cache.bank_key(world, key, 16),
        bank_cache.bank_key(world, jax.random.key(5), 16),
        bank_cache.bank_key(world, key, 32),
        bank_cache.bank_key(LetterWorld(LetterConfig(grid_size=5, letters=("a", "c"), counts=2)),
                            key, 16),
    }
    assert len(names) == 4 and bank_cache.bank_key(world, jax.random.key(4), 16) in names


def test_caching_off_samples_every_time(world, monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", "off")
    expected = world.with_map_bank(jax.random.key(1), world.default_params, num_maps=8)
    params = bank_cache.with_map_bank(world, world.default_params, jax.random.key(1), 8)
    np.testing.assert_array_equal(np.asarray(params.map_bank), np.asarray(expected.map_bank))
