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

# The heaviest test files first. Under `--dist loadfile` a file runs whole on one worker, and the
# workers take the files in the order of the collection (`--no-loadscope-reorder` in
# pyproject.toml; xdist's own order is by number of tests, which can leave a long file of few
# tests to the end while the other worker idles). Longest first keeps the two workers within about
# one small file of each other. Seconds per file, each test file alone in one process
# (`-n 0 --durations=0`, fresh compile cache, 2-core CPU, 2026-11-30); files not listed take
# under 10 s and keep their collection order after these.
FILE_SECONDS = {
    "envs/test_zone_physics.py": 242, "envs/test_arm_env.py": 200, "envs/test_arm_physics.py": 183,
    "envs/test_arm_solver_gating.py": 130, "baselines/test_train_any_world.py": 126,
    "baselines/test_methods.py": 83, "envs/test_zone_camera.py": 99, "baselines/test_gcrl.py": 75,
    "baselines/test_ltl2action_curriculum.py": 85, "envs/test_zone_gym.py": 85,
    "test_benchmark_scripts.py": 66, "baselines/test_ltl2action.py": 64,
    "benchmark/test_bench.py": 59, "test_cli.py": 57, "envs/test_zone_world.py": 56,
    "test_brax.py": 53, "baselines/test_ppo.py": 52, "baselines/test_rad_pretrain.py": 52,
    "baselines/test_rad_table.py": 51, "baselines/test_rad_curriculum.py": 51,
    "baselines/test_hosts.py": 49, "envs/test_letter_maps.py": 48, "envs/test_multi_batch.py": 47,
    "automata/test_automata_semantics.py": 47, "baselines/test_persistence.py": 44,
    "baselines/test_scoring.py": 41, "envs/test_zone_backends.py": 41,
    "envs/test_multi_zone.py": 40, "envs/test_zone_env.py": 39, "envs/test_batch_reset.py": 39,
    "baselines/test_rad.py": 24, "test_examples.py": 32, "envs/test_bad_input.py": 32,
    "eval/test_long_horizon.py": 31, "baselines/test_rad_encoder.py": 30,
    "baselines/test_ltl2action_pretrain.py": 30, "baselines/test_sharded.py": 29,
    "eval/test_evaluate.py": 28, "envs/test_zone_motion.py": 27, "test_train_profile.py": 27,
    "envs/test_arm_ik.py": 24, "test_coordinator.py": 21, "test_tasks.py": 20,
    "baselines/test_cli_bad_input.py": 17, "envs/test_arm_geometry.py": 16,
    "benchmark/test_report.py": 16, "test_extension.py": 14, "eval/test_original_ldba.py": 13,
    "automata/test_automata_search.py": 12, "baselines/test_gcrl_primitives.py": 12,
    "envs/test_letter.py": 12, "automata/test_automata_stepping.py": 12,
    "specs/test_spec_sequences.py": 12, "envs/test_multi_gym.py": 11, "eval/test_planner.py": 11,
}


def pytest_collection_modifyitems(config, items):
    here = Path(__file__).parent
    files = {}  # test file -> (minus its seconds, its first position): a stable sort by file
    for index, item in enumerate(items):
        if item.path not in files:
            try:
                name = item.path.relative_to(here).as_posix()
            except ValueError:
                name = None
            files[item.path] = (-FILE_SECONDS.get(name, 0), index)
    items.sort(key=lambda item: files[item.path])  # a file's tests keep their order
