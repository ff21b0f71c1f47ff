"""specrl_jax's on-disk caches, under one environment variable.

`SPECRL_JAX_CACHE_DIR` names the root (default `~/.cache/specrl_jax`): JAX's persistent
compilation cache lives in `<root>/jax`, compiled automata in `<root>/automata`, reset banks in
`<root>/banks`, the methods' set-up tables (RAD's tables, GCRL-LTL's direction primitives) in
`<root>/tables`, the training runs' traced programs (`baselines.programs`) in `<root>/programs`.
Set it to `off` (or `0`, `false`, `no`, `none`) to use none. Importing `specrl_jax` switches
JAX's cache on (`enable_jax_cache`), so a new process reuses the compiled resets and steps of
earlier ones, unless JAX's cache directory was configured already (`JAX_COMPILATION_CACHE_DIR`
or `jax.config`), which is then left alone. Library users keep JAX's threshold (programs
compiling in under 1 s are not stored); the `specrl-jax` command stores every program
(`CLI_MIN_COMPILE_SECONDS`), so that a second identical run compiles nothing.
`JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS` overrides both.
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import zipfile
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

ENV_VAR = "SPECRL_JAX_CACHE_DIR"
OFF_VALUES = ("off", "0", "false", "no", "none")
#: the command line stores every compiled program: the dozens under 1 s add up to seconds
CLI_MIN_COMPILE_SECONDS = 0.0
MIN_COMPILE_TIME_VAR = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"


def root() -> str | None:
    """The cache root (user-expanded), or None when caching is switched off."""
    value = os.environ.get(ENV_VAR, os.path.join("~", ".cache", "specrl_jax"))
    if value.strip().lower() in OFF_VALUES or not value.strip():
        return None
    return os.path.expanduser(value)


def _below_root(name: str) -> str | None:
    base = root()
    return None if base is None else os.path.join(base, name)


def jax_dir() -> str | None:
    """Directory of JAX's persistent compilation cache, or None (off)."""
    return _below_root("jax")


def automata_dir() -> str | None:
    """Directory of the compiled-automata cache, or None (off)."""
    return _below_root("automata")


def banks_dir() -> str | None:
    """Directory of the reset-bank cache (`envs.bank_cache`), or None (off)."""
    return _below_root("banks")


def tables_dir() -> str | None:
    """Directory of the methods' cached set-up tables (RAD's DFA banks and embeddings, GCRL-LTL's
    direction primitives), or None."""
    return _below_root("tables")


def programs_dir() -> str | None:
    """Directory of the traced programs of training runs (`baselines.programs`), or None (off)."""
    return _below_root("programs")


def digest(payload: dict, source_folders: tuple[str, ...] = ()) -> str:
    """Hex digest of `payload` (JSON-serialisable) and every `*.py` file of `source_folders`: a
    cache entry's name, changed by any input or source change."""
    import hashlib
    import json
    import pathlib

    sources = hashlib.sha256()
    for folder in source_folders:
        for path in sorted(pathlib.Path(folder).glob("*.py")):
            sources.update(path.read_bytes())
    text = json.dumps({**payload, "sources": sources.hexdigest()}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


@functools.cache
def package_digest() -> str:
    """Hex digest of every file of the specrl_jax package (sources and shipped data, without
    bytecode and `benchmark/results`, results rather than inputs): changed by any change of it."""
    import hashlib
    import pathlib

    package = pathlib.Path(__file__).resolve().parent
    results = package / "benchmark" / "results"
    files = hashlib.sha256()
    for path in sorted(package.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts and results not in path.parents:
            files.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes())
    return files.hexdigest()


def in_package(*objects: Any) -> bool:
    """Whether each object (a class, function or instance) is defined in the specrl_jax package,
    whose files `package_digest` covers (a user's registered method or world is not)."""
    modules = (getattr(o, "__module__", None) or type(o).__module__ for o in objects)
    return all(m == __package__ or m.startswith(f"{__package__}.") for m in modules)


#: the distributions whose versions name a cache entry of computed results or traced programs
DISTRIBUTIONS = ("jax", "jaxlib", "numpy", "flax", "optax", "chex", "mujoco", "mujoco-core", "mujoco-mjx",
                 "warp-lang", "spottl")


def runtime() -> dict:
    """What besides the inputs and the package decides a computed result or a traced program:
    the versions of `DISTRIBUTIONS` (None: not installed), JAX's settings (less its caches' and
    logging's), and the devices (platform, kind, count) and processes."""
    from importlib import metadata

    import jax

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    settings = {k: v for k, v in jax.config.values.items()
                if not any(word in k for word in ("cache", "log_compiles", "explain"))}
    return {"versions": {name: version(name) for name in DISTRIBUTIONS}, "jax_config": settings,
            "devices": [(d.platform, d.device_kind) for d in jax.devices()],
            "processes": jax.process_count()}


def load_arrays(directory: str | None, name: str) -> dict[str, np.ndarray] | None:
    """The arrays of `<directory>/<name>.npz`, or None (no directory, missing or unreadable)."""
    import numpy as np  # here, not at the top: `import specrl_jax` stays light

    if directory is None:
        return None
    try:
        with np.load(os.path.join(directory, name + ".npz")) as data:
            return {key: data[key] for key in data.files}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return None


def save_arrays(directory: str | None, name: str, arrays: dict[str, np.ndarray]) -> None:
    """Write `<directory>/<name>.npz` atomically (temporary file + rename); skipped without a
    directory or when it is not writable."""
    import numpy as np  # here, not at the top: `import specrl_jax` stays light

    if directory is None:
        return
    try:
        os.makedirs(directory, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, os.path.join(directory, name + ".npz"))
    except OSError:
        return


def load_tree(directory: str | None, name: str, template: Any) -> Any | None:
    """`template`'s tree holding the arrays of `<directory>/<name>.npz` (`save_tree`), or None
    (no directory, missing, unreadable, or of other leaves, shapes or dtypes)."""
    import jax  # here, not at the top: `import specrl_jax` stays light

    stored = load_arrays(directory, name)
    leaves, structure = jax.tree.flatten(template)
    if stored is None or len(stored) != len(leaves):
        return None
    read = [stored.get(f"leaf_{i}") for i in range(len(leaves))]
    if any(r is None or r.shape != tuple(x.shape) or r.dtype != x.dtype
           for r, x in zip(read, leaves)):
        return None
    return jax.tree.unflatten(structure, [jax.numpy.asarray(r) for r in read])


def save_tree(directory: str | None, name: str, tree: Any) -> None:
    """Write the arrays of `tree` to `<directory>/<name>.npz` (`save_arrays`), read back into
    its structure by `load_tree`."""
    import jax  # here, not at the top: `import specrl_jax` stays light
    import numpy as np

    leaves = jax.device_get(jax.tree.leaves(tree))
    save_arrays(directory, name, {f"leaf_{i}": np.asarray(x) for i, x in enumerate(leaves)})


def enable_jax_cache(min_compile_seconds: float | None = None) -> str | None:
    """Point JAX's persistent compilation cache at `jax_dir()`; returns the directory in use.

    Leaves a directory configured by the user (environment or `jax.config`) as it is, and does
    nothing when caching is off. `min_compile_seconds` (None: JAX's 1 s) is the shortest
    compilation stored, unless the environment sets `MIN_COMPILE_TIME_VAR`. Cheap: before JAX
    is imported it only sets JAX's environment variables, which JAX reads on import.
    """
    directory = jax_dir()
    if "jax" not in sys.modules:
        if directory is None:
            return os.environ.get("JAX_COMPILATION_CACHE_DIR")
        os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", directory)
        if min_compile_seconds is not None:
            os.environ.setdefault(MIN_COMPILE_TIME_VAR, str(min_compile_seconds))
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    import jax

    if min_compile_seconds is not None and MIN_COMPILE_TIME_VAR not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_seconds)
    if jax.config.jax_compilation_cache_dir or directory is None:
        return jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", directory)
    return directory
