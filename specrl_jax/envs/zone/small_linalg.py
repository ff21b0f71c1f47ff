"""Cholesky factor and solve for the small dense matrices of MJX's physics, as plain arithmetic.

MJX-JAX factors the mass matrix (`smooth.factor_m`, nv x nv: Car 11, Ant 14) and, in every
Newton iteration, the solver's Hessian (`solver._update_gradient`) with
`jax.scipy.linalg.cho_factor` / `cho_solve`. On a GPU these become library calls (a batched
factorisation, then triangular solves) that XLA cannot fuse with the surrounding code. Here the
same factorisation is written out entry by entry for a static n, so that under `vmap` it is
elementwise arithmetic over the batch, which XLA fuses. The results equal the library's to
rounding (not bitwise).

`small_cholesky()` puts these functions in place of `jax.scipy.linalg.cho_factor` / `cho_solve`
for the duration of a `with` block (matrices larger than `MAX_N` keep the library's); `Physics`
opens it around its tracing when `Solver.small_cholesky` is set. The replacement is
process-global while the block is open, as `contact_frame.c_contact_frame`'s is.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import jax
import jax.numpy as jnp
import jax.scipy.linalg

#: Largest n written out (about n^3 / 6 multiply-adds per factorisation).
MAX_N = 24
_LOCK = threading.RLock()
_LIBRARY = (jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve)


def cholesky_lower(a: jax.Array) -> jax.Array:
    """L with a = L L^T for a symmetric positive definite `a` ([..., n, n]); zeros above the
    diagonal; NaN where `a` is not positive definite (as the library's)."""
    n = a.shape[-1]
    rows: list[list[jax.Array]] = [[None] * n for _ in range(n)]
    for j in range(n):
        diag = a[..., j, j] - sum((rows[j][k] ** 2 for k in range(j)), jnp.zeros_like(a[..., 0, 0]))
        rows[j][j] = jnp.sqrt(diag)
        for i in range(j + 1, n):
            off = a[..., i, j] - sum((rows[i][k] * rows[j][k] for k in range(j)),
                                     jnp.zeros_like(a[..., 0, 0]))
            rows[i][j] = off / rows[j][j]
    zero = jnp.zeros_like(a[..., 0, 0])
    return jnp.stack([jnp.stack([rows[i][j] if j <= i else zero for j in range(n)], -1)
                      for i in range(n)], -2)


def cho_factor(a: jax.Array, lower: bool = False, **kwargs):
    """`jax.scipy.linalg.cho_factor` for n <= `MAX_N`: `(c, lower)`, `c` triangular with zeros
    in the other triangle."""
    if a.shape[-1] > MAX_N or kwargs.get("overwrite_a") or a.ndim < 2:
        return _LIBRARY[0](a, lower=lower, **kwargs)
    factor = cholesky_lower(a)
    return (factor, True) if lower else (jnp.swapaxes(factor, -1, -2), False)


def cho_solve(c_and_lower: tuple[jax.Array, bool], b: jax.Array, **kwargs) -> jax.Array:
    """`jax.scipy.linalg.cho_solve` for n <= `MAX_N`: x with (L L^T) x = b, `b` [n] or [n, k]
    (leading batch axes of `c` and `b` broadcast)."""
    c, lower = c_and_lower
    n = c.shape[-1]
    if n > MAX_N or c.ndim != 2:
        return _LIBRARY[1](c_and_lower, b, **kwargs)
    factor = c if lower else c.T  # lower factor L
    entries = [b[i] for i in range(n)]  # each [] or [k]
    y: list[jax.Array] = []
    for i in range(n):  # L y = b
        y.append((entries[i] - sum((factor[i, k] * y[k] for k in range(i)),
                                   jnp.zeros_like(entries[i]))) / factor[i, i])
    x: list[jax.Array] = [None] * n
    for i in reversed(range(n)):  # L^T x = y
        x[i] = (y[i] - sum((factor[k, i] * x[k] for k in range(i + 1, n)),
                           jnp.zeros_like(y[i]))) / factor[i, i]
    return jnp.stack(x, 0)


@contextlib.contextmanager
def small_cholesky() -> Iterator[None]:
    """Within the block, `jax.scipy.linalg.cho_factor` / `cho_solve` are this module's (for
    what is traced there); the library's are restored on exit, also on error. Re-entrant."""
    with _LOCK:
        previous = (jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve)
        jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve = cho_factor, cho_solve
        try:
            yield
        finally:
            jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve = previous


__all__ = ["MAX_N", "cho_factor", "cho_solve", "cholesky_lower", "small_cholesky"]
