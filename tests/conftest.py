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
# the suite compiles far more than it runs. At LLVM optimisation level 0 XLA compiles CPU programs
# about a third faster (the Point world's batched step); with XLA:CPU's loop emitters instead of its
# fusion emitters about half again (the arm's contact step 25 -> 9 s, a tiny GenZ-LTL update
# 19 -> 11 s). The learning tests' loops run no slower.
TEST_XLA_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")
_flags = os.environ.get("XLA_FLAGS", "")  # a flag the caller set stays as set
os.environ["XLA_FLAGS"] = " ".join(
    filter(None, (_flags, *(f for f in TEST_XLA_FLAGS if f.split("=")[0] not in _flags))))

# one OpenBLAS thread per process: the suite's numpy and SciPy calls are on tiny matrices, where
# OpenBLAS's threads cost more than they give (the arm's reference motor solve, SciPy's L-BFGS-B,
# runs 5x faster), and the test processes already fill the cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import specrl_jax  # noqa: E402,F401  (switches JAX's cache on, in the directory chosen above)
