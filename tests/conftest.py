"""Test-wide settings: CPU-friendly JAX with the persistent compilation cache.

The caches live under `$SPECRL_JAX_CACHE_DIR` (`specrl_jax.cache`), by default the repository's
`.jax_cache/` for tests (JAX's in `.jax_cache/jax`).
"""

import os

os.environ.setdefault(
    "SPECRL_JAX_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".jax_cache")
)

import jax  # noqa: E402  (after the cache directory is chosen)

from specrl_jax import cache  # noqa: E402

if cache.jax_dir() is not None:
    jax.config.update("jax_compilation_cache_dir", cache.jax_dir())
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
