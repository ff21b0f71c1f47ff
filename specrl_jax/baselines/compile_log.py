"""Ahead-of-time compilation that says what compiles and how long it took: a training's first
minutes on a CPU are compilation, and a silent wait reads as a hang. `in_background` runs a
compilation beside other work."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import jax

from specrl_jax.baselines import programs


def compile_logged(fn: Callable, args: tuple, what: str, log: Callable[[str], None] | None = None,
                   program_key: str | None = None, **jit_options: Any) -> Callable:
    """`jax.jit(fn, **jit_options)` compiled ahead of time for `args`.

    Args:
        fn: the function to compile.
        args: example arguments (static ones included, as `jit_options` names them).
        what: what compiles, for the messages ("the training step").
        log: hears "compiling <what> ..." and "compiled <what> in N s" (seconds when JAX's
            persistent cache holds it); None: silent.
        program_key: with `what`, names the traced program in the disk cache
            (`baselines.programs`): a digest of everything `fn` computes with beyond its
            arguments; None: traced every time.
        **jit_options: `jax.jit` options (`static_argnums`, `donate_argnums`, ...; with
            `program_key` only these two).

    Returns:
        The compiled executable; it takes `args` less the static ones.
    """
    if log is not None:
        log(f"compiling {what} ...")
    start = time.perf_counter()
    read = False
    if program_key is None:
        compiled = jax.jit(fn, **jit_options).lower(*args).compile()
    else:
        compiled, read = programs.compile_cached(fn, args, f"{program_key} {what}", **jit_options)
    if log is not None:
        how = " (its traced program read from the program cache)" if read else ""
        log(f"compiled {what} in {time.perf_counter() - start:.0f} s{how}")
    return compiled


def in_background(fn: Callable[..., Any], *args: Any) -> Future:
    """`fn(*args)` in another thread, under the caller's JAX settings that are kept per thread
    (x64, default matmul precision, default device); its error, if any, is the future's. The
    process waits for the thread at exit: leaving during an XLA compilation crashes."""
    settings = (jax.config.jax_enable_x64, jax.config.jax_default_matmul_precision,
                jax.config.jax_default_device)
    future: Future = Future()

    def run() -> None:
        x64, precision, device = settings
        try:
            with jax.enable_x64(x64), jax.default_matmul_precision(precision), \
                    jax.default_device(device):
                future.set_result(fn(*args))
        except BaseException as error:  # noqa: BLE001 (handed to whoever waits on the result)
            future.set_exception(error)

    threading.Thread(target=run).start()
    return future
