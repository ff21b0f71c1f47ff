"""Ahead-of-time compilation that says what compiles and how long it took: a training's first
minutes on a CPU are compilation, and a silent wait reads as a hang."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax


def compile_logged(fn: Callable, args: tuple, what: str, log: Callable[[str], None] | None = None,
                   **jit_options: Any) -> Callable:
    """`jax.jit(fn, **jit_options)` compiled ahead of time for `args`.

    Args:
        fn: the function to compile.
        args: example arguments (static ones included, as `jit_options` names them).
        what: what compiles, for the messages ("the training step").
        log: hears "compiling <what> ..." and "compiled <what> in N s" (seconds when JAX's
            persistent cache holds it); None: silent.
        **jit_options: `jax.jit` options (`static_argnums`, `donate_argnums`, ...).

    Returns:
        The compiled executable; it takes `args` less the static ones.
    """
    if log is not None:
        log(f"compiling {what} ...")
    start = time.perf_counter()
    compiled = jax.jit(fn, **jit_options).lower(*args).compile()
    if log is not None:
        log(f"compiled {what} in {time.perf_counter() - start:.0f} s")
    return compiled
