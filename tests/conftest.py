"""Test-wide settings: CPU-friendly JAX with the persistent compilation cache.

The caches live under `$SPECRL_JAX_CACHE_DIR` (`specrl_jax.cache`), by default the repository's
`.jax_cache/` for tests (JAX's in `.jax_cache/jax`).
"""

import os

os.environ.setdefault(
    "SPECRL_JAX_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".jax_cache")
)
# tests compile many small programs: keep those over half a second (the package's default is 1 s)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
# the suite compiles far more than it runs: at LLVM optimisation level 0 XLA compiles CPU programs
# about a third faster (the Point world's batched step), and the learning tests' loops run no slower
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = " ".join(
        filter(None, (os.environ.get("XLA_FLAGS"), "--xla_backend_optimization_level=0")))

import specrl_jax  # noqa: E402,F401  (switches JAX's cache on, in the directory chosen above)
