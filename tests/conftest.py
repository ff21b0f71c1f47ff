"""Test-wide settings: CPU-friendly JAX with the persistent compilation cache.

The caches live under `$SPECRL_JAX_CACHE_DIR` (`specrl_jax.cache`), by default the repository's
`.jax_cache/` for tests (JAX's in `.jax_cache/jax`).
"""

import os
from pathlib import Path

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

import specrl_jax  # noqa: F401  (switches JAX's cache on, in the directory chosen above)

# MuJoCo Warp's CPU kernels (the Warp backend's tests) at clang's -O0: their first compilation a
# third shorter (the nested-batch test 25 -> 17 s with a cold kernel cache), the same tolerances met
try:
    import warp

    warp.config.optimization_level = 0
except ImportError:
    pass

# The heaviest test files first. Under `--dist loadfile` a file runs whole on one worker, and the
# workers take the files in the order of the collection (`--no-loadscope-reorder` in
# pyproject.toml; xdist's own order is by number of tests, which can leave a long file of few
# tests to the end while the other worker idles). Seconds per file of those over 50 s, each alone
# in one process (`-n 0 --durations=0`, fresh compile cache, 2-core CPU, 2026-11-30); the other
# files follow in their collection order.
FILE_SECONDS = {
    "envs/test_zone_physics.py": 242, "envs/test_arm_env.py": 200, "envs/test_arm_physics.py": 183,
    "envs/test_arm_solver_gating.py": 130, "baselines/test_train_any_world.py": 126,
    "envs/test_zone_camera.py": 99, "baselines/test_ltl2action_curriculum.py": 85,
    "envs/test_zone_gym.py": 85, "baselines/test_methods.py": 83, "baselines/test_gcrl.py": 75,
    "test_benchmark_scripts.py": 66, "baselines/test_ltl2action.py": 64,
    "benchmark/test_bench.py": 59, "test_cli.py": 57, "envs/test_zone_world.py": 56,
    "test_brax.py": 53, "baselines/test_ppo.py": 52, "baselines/test_rad_pretrain.py": 52,
    "baselines/test_rad_table.py": 51, "baselines/test_rad_curriculum.py": 51,
}


def pytest_collection_modifyitems(config, items):
    here = Path(__file__).parent
    files = {}  # test file -> (minus its seconds, its first position): a stable sort by file
    for index, item in enumerate(items):
        if item.path not in files:
            name = item.path.relative_to(here).as_posix() if item.path.is_relative_to(here) else ""
            files[item.path] = (-FILE_SECONDS.get(name, 0), index)
    items.sort(key=lambda item: files[item.path])  # a file's tests keep their order
