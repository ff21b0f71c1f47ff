"""Traced programs on disk (`specrl_jax.cache.programs_dir()`): a second identical run compiles
its programs without tracing them again.

JAX's persistent compilation cache spares a second run XLA's compilation, not the tracing and
lowering that its key needs: seconds for a training step on a CPU, ten for the arm's batched
physics. An entry holds the program as `jax.export` serialises it (StableHLO) with the tree
structure of its result, named by the caller's `key` (a digest of everything that determines the
program, e.g. `benchmark.experiment.program_key`) and the structure, shapes, dtypes and shardings
of the arguments. A stored program is compiled as it was first compiled, so JAX's cache answers
that compilation. A program that `jax.export` refuses (a host callback, checkify's effect, a
custom call without a stable ABI) or that spans several devices is marked so and compiled as
`jax.jit` does, traced every time; an unreadable entry is traced and stored again. An entry
holds a pickled tree structure: read only caches you wrote, as with JAX's own.
"""

from __future__ import annotations

import pickle
import re
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from specrl_jax import cache


def _positions(argnums: int | Sequence[int]) -> tuple[int, ...]:
    return (argnums,) if isinstance(argnums, int) else tuple(argnums)


def _describe(structure: Any) -> str:
    """A tree structure as text, the same in every run: static metadata of a default repr is
    named without its address (an unpickled copy of it may not compare equal)."""
    return re.sub(r" at 0x[0-9a-fA-F]+", "", str(structure))


def _placement(leaf: Any) -> str:
    """A leaf's sharding as the entry's name holds it: one device's placements (a shape's none,
    a single device, a mesh of one) are one, as the exported program is the same for them."""
    sharding = getattr(leaf, "sharding", None)
    return "one device" if sharding is None or len(sharding.device_set) == 1 else repr(sharding)


def _entry_name(key: str, args: tuple, static_argnums: int | Sequence[int] = (),
               donate_argnums: int | Sequence[int] = ()) -> str:
    """The entry of the program `key` compiled for `args` (static ones by value, the others by
    structure, shape, dtype and sharding)."""
    static = _positions(static_argnums)
    dynamic = [a for i, a in enumerate(args) if i not in static]
    leaves, structure = jax.tree.flatten(dynamic)
    return "program_" + cache.digest({
        "key": key, "structure": _describe(structure),
        "leaves": [(repr(jax.typeof(x)), _placement(x)) for x in leaves],
        "static": [repr(args[i]) for i in sorted(static)],
        "donate": sorted(_positions(donate_argnums))})


def _flat(fn: Callable, args: tuple, static: tuple[int, ...], structure: Any,
          out_structure: list) -> Callable:
    """`fn` on the leaves of the non-static arguments, returning the leaves of its result (whose
    structure it appends to `out_structure`)."""

    def flat_fn(*leaves: jax.Array) -> list[jax.Array]:
        dynamic = iter(jax.tree.unflatten(structure, leaves))
        full = [a if i in static else next(dynamic) for i, a in enumerate(args)]
        out, out_tree = jax.tree.flatten(fn(*full))
        out_structure.append(out_tree)
        return out

    return flat_fn


#: an entry's mark for a program `jax.export` refuses, so that later runs do not try again
REFUSED = "refused"


def _load(name: str) -> tuple[jax.export.Exported, Any] | str | None:
    """The stored program `name` with its result's structure, `REFUSED`, or None (not stored,
    or unreadable)."""
    stored = cache.load_arrays(cache.programs_dir(), name)
    if stored is not None and REFUSED in stored:
        return REFUSED
    if stored is None or not {"exported", "out_structure"} <= stored.keys():
        return None
    try:
        return (jax.export.deserialize(bytearray(stored["exported"].tobytes())),
                pickle.loads(stored["out_structure"].tobytes()))
    except Exception:  # noqa: BLE001  (a damaged entry raises assorted types: trace it again)
        return None


def _export(fn: Callable, args: tuple, static: tuple[int, ...], structure: Any, leaves: list,
            name: str) -> tuple[jax.export.Exported, Any] | None:
    """`fn` traced and exported, with its result's structure, stored as `name`; None where
    `jax.export` refuses to export or serialise it or it spans several devices (whose
    assignment an entry does not keep), marked `REFUSED`. Without `flatbuffers`, `jax.export`'s
    serialiser, nothing is stored."""
    out_structure: list = []
    try:
        exported = jax.export.export(jax.jit(_flat(fn, args, static, structure, out_structure)))(
            *leaves)
    except (NotImplementedError, ValueError):  # a host callback, a custom call without a stable ABI
        exported = None
    serialised = None
    if exported is not None and exported.nr_devices == 1:
        try:
            serialised = exported.serialize()
        except ImportError:  # no flatbuffers: the program is used, not stored
            return exported, out_structure[-1]
        except NotImplementedError:  # an effect without a serialised form (checkify's errors)
            pass
    try:  # static metadata a pickle cannot carry (a local class): the program is not stored
        structure_bytes = None if serialised is None else pickle.dumps(out_structure[-1])
    except (pickle.PicklingError, AttributeError, TypeError):
        structure_bytes = None
    if structure_bytes is None:
        cache.save_arrays(cache.programs_dir(), name, {REFUSED: np.zeros(0)})
        return None
    cache.save_arrays(cache.programs_dir(), name, {
        "exported": np.frombuffer(serialised, np.uint8),
        "out_structure": np.frombuffer(structure_bytes, np.uint8)})
    return exported, out_structure[-1]


def compile_cached(fn: Callable, args: tuple, key: str, static_argnums: int | Sequence[int] = (),
                   donate_argnums: int | Sequence[int] = ()) -> tuple[Callable, bool]:
    """`jax.jit(fn, static_argnums=..., donate_argnums=...)` compiled for `args`, its traced
    program read from the disk cache when stored there under `key`, else traced and stored.

    Args:
        fn: the function to compile.
        args: example arguments, static ones included.
        key: names the program: a digest of everything `fn` computes with beyond its arguments
            (settings, closed-over data, sources, versions).
        static_argnums: as `jax.jit`'s.
        donate_argnums: as `jax.jit`'s.

    Returns:
        `(compiled, read)`: `compiled` takes `args` less the static ones, as a compiled `jax.jit`
        does; `read`: the program came from the disk cache (it was not traced).
    """
    static = _positions(static_argnums)
    donate = _positions(donate_argnums)
    positions = [i for i in range(len(args)) if i not in static]
    leaves, structure = jax.tree.flatten([args[i] for i in positions])
    owners = [i for i in positions for _ in jax.tree.leaves(args[i])]  # each leaf's argument
    donated = tuple(j for j, i in enumerate(owners) if i in donate)
    name = _entry_name(key, args, static, donate)
    loaded = _load(name)
    read = isinstance(loaded, tuple)
    if loaded is None:
        loaded = _export(fn, args, static, structure, leaves, name)
    if not isinstance(loaded, tuple):  # refused: compiled as `jax.jit` does, traced every time
        plain = jax.jit(fn, static_argnums=static, donate_argnums=donate)
        return plain.lower(*args).compile(), False
    exported, out_structure = loaded
    try:
        compiled = jax.jit(exported.call, donate_argnums=donated).lower(*leaves).compile()
    except Exception:
        if not read:
            raise
        # a stored entry that does not fit these arguments (another platform): traced instead
        plain = jax.jit(fn, static_argnums=static, donate_argnums=donate)
        return plain.lower(*args).compile(), False
    expected = _describe(structure)

    def run(*call_args: Any) -> Any:
        call_leaves, call_structure = jax.tree.flatten(list(call_args))
        if _describe(call_structure) != expected:
            raise TypeError(f"expected arguments of structure {expected}, got {call_structure}")
        return jax.tree.unflatten(out_structure, compiled(*call_leaves))

    return run, read
