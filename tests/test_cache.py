"""One cache variable (SPECRL_JAX_CACHE_DIR), JAX's cache on for library users, shared compiles."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import cache
from specrl_jax.automata import cache as automata_cache
from specrl_jax.envs import base
from specrl_jax.envs.letter import LetterConfig, LetterWorld

PROBE = "import specrl_jax, jax; print(jax.config.jax_compilation_cache_dir)"


def _probe(**env: str) -> str:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "SPECRL_JAX"))}
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env={**clean, **env}, capture_output=True, text=True,
        timeout=120, check=True,
    )
    return out.stdout.strip()


def test_one_variable_names_both_caches(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    assert cache.jax_dir() == str(tmp_path / "jax")
    assert cache.automata_dir() == str(tmp_path / "automata") == automata_cache.cache_dir()
    monkeypatch.delenv("SPECRL_JAX_CACHE_DIR")
    assert cache.root() == os.path.expanduser(os.path.join("~", ".cache", "specrl_jax"))


def test_off_disables_both_caches(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", "off")
    assert cache.jax_dir() is None and automata_cache.cache_dir() is None
    automata_cache.save("k", {"a": np.zeros(2)})  # nowhere to write: a no-op, no error
    assert automata_cache.load("k") is None
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    automata_cache.save("k", {"a": np.arange(3)})
    assert automata_cache.load("k")["a"].tolist() == [0, 1, 2]
    assert os.listdir(tmp_path / "automata") == ["k.npz"]


def test_importing_the_package_turns_jax_cache_on(tmp_path):
    # before: only the CLI switched it on, so library users compiled everything in every process
    assert _probe(SPECRL_JAX_CACHE_DIR=str(tmp_path)) == str(tmp_path / "jax")
    assert _probe(SPECRL_JAX_CACHE_DIR="off") == "None"
    assert _probe(SPECRL_JAX_CACHE_DIR=str(tmp_path), JAX_COMPILATION_CACHE_DIR="/elsewhere") == (
        "/elsewhere"
    )


def test_envs_of_one_config_share_compiled_eager_steps():
    config = LetterConfig(grid_size=5, letters=("a", "b"), counts=1)
    first, second = LetterWorld(config), LetterWorld(config)
    assert base._compiled(first) is base._compiled(second)
    other = LetterWorld(LetterConfig(grid_size=5, letters=("a", "b"), counts=2))
    assert base._compiled(first) is not base._compiled(other)
    _, state = first.reset(jax.random.key(0))
    first.step(jax.random.key(1), state, 1)
    out = second.step(jax.random.key(2), state, jnp.int32(2))  # scalar or array: one compile
    assert base._compiled(first).step._cache_size() == 1
    assert np.array_equal(out[1].agent, (state.agent + np.array([0, -1])) % 5)


def test_second_gymnasium_make_reuses_the_compiled_functions():
    import gymnasium

    import specrl_jax.gym  # noqa: F401

    one, two = gymnasium.make("LetterLTL0-v0"), gymnasium.make("LetterLTL0-v0", max_steps=9)
    assert one.unwrapped._step is two.unwrapped._step
    assert one.unwrapped._reset is two.unwrapped._reset
    vec_one = gymnasium.make_vec("LetterLTL0-v0", num_envs=2)
    vec_two = gymnasium.make_vec("LetterLTL0-v0", num_envs=2)
    assert vec_one._step is vec_two._step
    assert vec_one._step is not gymnasium.make_vec("LetterLTL0-v0", num_envs=3)._step
