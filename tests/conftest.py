"""Test-wide settings: CPU-friendly JAX with the persistent compilation cache."""

import os

import jax

jax.config.update(
    "jax_compilation_cache_dir",
    os.environ.get("SPECRL_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".jax_cache")),
)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
