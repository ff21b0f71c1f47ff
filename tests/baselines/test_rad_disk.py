"""RAD's set-up tables on disk (baselines/rad/disk.py): a curriculum's DFAs and a bank's
embedding table come back from the cache equal to what was computed, the table's builder runs
once per distinct input, and nothing is stored with caching off."""

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, cache
from specrl_jax.baselines.rad import disk
from specrl_jax.baselines.rad.table import EmbeddingTable
from specrl_jax.specs import CurriculumSampler, curriculum
from specrl_jax.tasks.dfa_source import curriculum_dfas

COLOURS = ("blue", "green", "magenta", "yellow")


def _table(scale: float) -> EmbeddingTable:
    return EmbeddingTable(jnp.arange(6.0).reshape(3, 2) * scale, jnp.asarray([0, -1, 1, 2]),
                          jnp.asarray([[1]], jnp.int32), jnp.asarray([0], jnp.int32))


def test_curriculum_dfas_and_tables_come_back_from_the_disk_as_computed(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    sampler = CurriculumSampler(curriculum("deepltl/zone"), len(COLOURS))
    alphabet = automata.zero_or_one(len(COLOURS))
    fresh = curriculum_dfas(sampler, COLOURS, alphabet, 4, seed=1)
    stored = disk.curriculum_dfas(sampler, COLOURS, alphabet, 4, seed=1)  # computes and stores
    read = disk.curriculum_dfas(sampler, COLOURS, alphabet, 4, seed=1)  # reads
    assert len(list((tmp_path / "tables").glob("rad_curriculum_*.npz"))) == 1
    for tasks in (stored, read):
        assert tasks.formulas == fresh.formulas
        for a, b in zip(jax.tree.leaves(tasks.bank), jax.tree.leaves(fresh.bank)):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    assert disk.curriculum_dfas(sampler, COLOURS, alphabet, 4, seed=2).formulas != fresh.formulas

    built = []

    def build(scale):
        built.append(scale)
        return _table(scale)

    encoder = {"params": {"w": jnp.ones((2, 2))}}
    first = disk.embedding_table(encoder, fresh.bank, 8, 100, lambda: build(1.0))
    again = disk.embedding_table(encoder, fresh.bank, 8, 100, lambda: build(1.0))
    other = disk.embedding_table({"params": {"w": jnp.zeros((2, 2))}}, fresh.bank, 8, 100,
                                 lambda: build(2.0))
    assert built == [1.0, 2.0]  # the second call read the first's table
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(first)):
        assert np.array_equal(a, b)
    assert np.array_equal(other.rows, _table(2.0).rows)


def test_nothing_is_stored_with_caching_off(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, "off")
    monkeypatch.chdir(tmp_path)
    built = []
    for _ in range(2):
        disk.embedding_table({"w": jnp.ones(2)}, {"x": jnp.ones(3)}, 8, 100,
                             lambda: built.append(1) or _table(1.0))
    assert built == [1, 1] and not list(tmp_path.rglob("*.npz"))
