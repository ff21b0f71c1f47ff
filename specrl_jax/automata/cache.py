"""Disk cache of compiled specs: one `.npz` per (formula, propositions, alphabet, caps, versions).

Directory: `specrl_jax.cache.automata_dir()`, i.e. `$SPECRL_JAX_CACHE_DIR/automata` (default
`~/.cache/specrl_jax/automata`; no disk cache when `SPECRL_JAX_CACHE_DIR=off`). Writes are
atomic (temporary file + rename), and an unreadable entry is treated as a miss.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence

import numpy as np
import spot

import specrl_jax
from specrl_jax import cache as _root_cache

#: bump when the compiled layout or the construction changes
FORMAT_VERSION = 3


def cache_dir() -> str | None:
    """The automata cache directory, or None when caching is off."""
    return _root_cache.automata_dir()


def cache_key(formula: str, propositions: Sequence[str], alphabet: np.ndarray, **options) -> str:
    """Hex digest naming an entry; any change of input, option or library version changes it."""
    payload = {
        "formula": formula,
        "propositions": list(propositions),
        "alphabet_shape": list(alphabet.shape),
        "alphabet": np.packbits(alphabet.astype(bool)).tobytes().hex(),
        "options": options,
        "spot": spot.version(),
        "numpy": np.__version__,
        "specrl_jax": specrl_jax.__version__,
        "format": FORMAT_VERSION,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def load(key: str) -> dict[str, np.ndarray] | None:
    """The arrays stored under `key`, or None (missing, unreadable, or caching off)."""
    return _root_cache.load_arrays(cache_dir(), key)


def save(key: str, arrays: dict[str, np.ndarray]) -> None:
    """Store `arrays` under `key` (skipped if caching is off or the directory is not writable)."""
    _root_cache.save_arrays(cache_dir(), key, arrays)
