"""specrl_jax's on-disk caches, under one environment variable.

`SPECRL_JAX_CACHE_DIR` names the root (default `~/.cache/specrl_jax`): JAX's persistent
compilation cache lives in `<root>/jax`, compiled automata in `<root>/automata`. Set it to `off`
(or `0`, `false`, `no`, `none`) to use neither. Importing `specrl_jax` switches JAX's cache on
(`enable_jax_cache`), so a new process reuses the compiled resets and steps of earlier ones,
unless JAX's cache directory was configured already (`JAX_COMPILATION_CACHE_DIR` or
`jax.config`), which is then left alone.
"""

from __future__ import annotations

import os
import sys

ENV_VAR = "SPECRL_JAX_CACHE_DIR"
OFF_VALUES = ("off", "0", "false", "no", "none")
#: compilations faster than this are not written to JAX's cache (JAX's own default is 1 s)
MIN_COMPILE_SECONDS = 1.0


def root() -> str | None:
    """The cache root (user-expanded), or None when caching is switched off."""
    value = os.environ.get(ENV_VAR, os.path.join("~", ".cache", "specrl_jax"))
    if value.strip().lower() in OFF_VALUES or not value.strip():
        return None
    return os.path.expanduser(value)


def jax_dir() -> str | None:
    """Directory of JAX's persistent compilation cache, or None (off)."""
    base = root()
    return None if base is None else os.path.join(base, "jax")


def automata_dir() -> str | None:
    """Directory of the compiled-automata cache, or None (off)."""
    base = root()
    return None if base is None else os.path.join(base, "automata")


def enable_jax_cache(min_compile_seconds: float = MIN_COMPILE_SECONDS) -> str | None:
    """Point JAX's persistent compilation cache at `jax_dir()`; returns the directory in use.

    Leaves a directory configured by the user (environment or `jax.config`) as it is, and does
    nothing when caching is off. Cheap: before JAX is imported it only sets JAX's environment
    variables, which JAX reads on import.
    """
    directory = jax_dir()
    if "jax" not in sys.modules:
        if directory is None:
            return os.environ.get("JAX_COMPILATION_CACHE_DIR")
        os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", directory)
        os.environ.setdefault(
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", str(min_compile_seconds)
        )
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    import jax

    if jax.config.jax_compilation_cache_dir or directory is None:
        return jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", directory)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_seconds)
    return directory
