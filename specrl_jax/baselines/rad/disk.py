"""RAD's set-up tables on disk (`specrl_jax.cache.tables_dir()`): a curriculum's DFAs (thousands of
Spot translations) and the embedding table of a bank's reachable states (the encoder run over
them), each seconds to minutes on a CPU and the same in every run with the same inputs.

An entry is named by the digest of every input (formulas and alphabet, or the encoder's
parameters and the bank's arrays) and of the sources that compute it; a missing or unreadable
entry is computed again and stored. Without a cache directory nothing is read or written.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import cache
from specrl_jax.automata.rad_sampler import DFABank
from specrl_jax.baselines.rad import table as rad_table
from specrl_jax.specs import CurriculumSampler
from specrl_jax.tasks import dfa_source
from specrl_jax.tasks.dfa_source import CurriculumDFAs
from specrl_jax.tasks.sources import ByContent

_PACKAGE = pathlib.Path(__file__).resolve().parents[2]
#: the sources a curriculum's DFAs and a table depend on
_SOURCES = tuple(str(_PACKAGE / sub) for sub in ("automata", "tasks", "specs", "baselines/rad"))


def _spot_version() -> str:
    import spot

    return spot.version()


def curriculum_dfas(sampler: CurriculumSampler, propositions: Sequence[str], alphabet: np.ndarray,
                    per_stage: int, seed: int = 0) -> CurriculumDFAs:
    """`dfa_source.curriculum_dfas`, read from the disk cache when stored there."""
    alphabet = np.asarray(alphabet, bool)
    name = "rad_curriculum_" + cache.digest({
        "curriculum": repr(sampler.curriculum), "propositions": list(propositions),
        "alphabet": alphabet.astype(int).tolist(), "per_stage": per_stage, "seed": seed,
        "spot": _spot_version()}, _SOURCES)
    stored = cache.load_arrays(cache.tables_dir(), name)
    if stored is not None and "formulas" in stored:
        bank = DFABank(**{f.name: jnp.asarray(stored[f.name]) for f in dataclasses.fields(DFABank)})
        return CurriculumDFAs(bank, json.loads(str(stored["formulas"])))
    tasks = dfa_source.curriculum_dfas(sampler, propositions, alphabet, per_stage, seed)
    arrays = {f.name: np.asarray(getattr(tasks.bank, f.name)) for f in dataclasses.fields(DFABank)}
    cache.save_arrays(cache.tables_dir(), name, {**arrays, "formulas": np.asarray(
        json.dumps(tasks.formulas))})
    return tasks


def embedding_table(encoder_params: Any, bank: DFABank, num_layers: int, max_rows: int,
                    build: Callable[[], rad_table.EmbeddingTable]) -> rad_table.EmbeddingTable:
    """`build()`, the embedding table of `bank` under `encoder_params` (of `num_layers` rounds, at
    most `max_rows` rows), read from the disk cache when stored there. `build`'s errors pass."""
    name = "rad_table_" + cache.digest({
        "encoder": ByContent(encoder_params).digest, "bank": ByContent(bank).digest,
        "num_layers": num_layers, "max_rows": max_rows, "jax": jax.__version__,
        "platform": jax.default_backend()}, _SOURCES)
    fields = [f.name for f in dataclasses.fields(rad_table.EmbeddingTable)]
    stored = cache.load_arrays(cache.tables_dir(), name)
    if stored is not None and all(f in stored for f in fields):
        return rad_table.EmbeddingTable(**{f: jnp.asarray(stored[f]) for f in fields})
    table = build()
    cache.save_arrays(cache.tables_dir(), name, {f: np.asarray(getattr(table, f)) for f in fields})
    return table

