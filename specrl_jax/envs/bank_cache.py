"""Disk cache of reset banks (`env.with_map_bank`): one `.npz` per (world config, bank size, key,
JAX version and platform, the world's source).

A second training with the same settings reads its bank in milliseconds instead of sampling it
again (LetterWorld's 4,096 exact maps take seconds on a CPU). Directory:
`specrl_jax.cache.banks_dir()`, i.e. `$SPECRL_JAX_CACHE_DIR/banks` (none when caching is off).
The bank is the one `with_map_bank` samples, bit for bit: the key names every input of it,
and an unreadable entry is sampled again.
"""

from __future__ import annotations

import inspect
import pathlib
from typing import Any

import jax
import numpy as np

from specrl_jax import cache


def bank_key(world: Any, key: jax.Array, num_maps: int) -> str:
    """Hex digest naming the bank of `world.with_map_bank(key, ..., num_maps)`; any change of
    config, size, key, JAX, platform or a source file of the world's package changes it."""
    folder = pathlib.Path(inspect.getfile(type(world))).parent
    return cache.digest({
        "world": f"{type(world).__module__}.{type(world).__qualname__}",
        "config": repr(world.config),
        "num_maps": num_maps,
        "key": np.asarray(jax.random.key_data(key)).tobytes().hex(),
        "jax": jax.__version__,
        "platform": jax.default_backend(),
    }, (str(folder),))


def with_map_bank(world: Any, params: Any, key: jax.Array, num_maps: int) -> Any:
    """`world.with_map_bank(key, params, num_maps=num_maps)`, its bank read from the disk cache
    when stored there, else sampled (waiting for it) and stored."""
    name = bank_key(world, key, num_maps)
    stored = cache.load_arrays(cache.banks_dir(), name)
    if stored is not None and "map_bank" in stored:
        return params.replace(map_bank=jax.numpy.asarray(stored["map_bank"]))
    params = jax.block_until_ready(world.with_map_bank(key, params, num_maps=num_maps))
    cache.save_arrays(cache.banks_dir(), name, {"map_bank": np.asarray(params.map_bank)})
    return params
