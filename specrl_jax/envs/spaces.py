"""Observation and action spaces, with the checks done at the Python boundary.

Shape and dtype checks are static, so they also run while tracing under `jit`/`vmap`;
value checks (range, NaN) run on concrete arrays, including the batch of an eager `vmap`
(`BatchedEnv.step` called outside `jit`). On the traced path `is_valid` and `sanitize` give
invalid actions a defined behaviour instead (see `Env.step`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def _concrete_value(x: Any) -> np.ndarray | None:
    """`x` as numpy when its values are known now, else None.

    Under an eager `jax.vmap` an argument is a batching tracer wrapping the concrete batch; its
    values are checked like an unbatched action's (every tracer of a `jit` is skipped).
    """
    while isinstance(x, jax.core.Tracer):
        # batching tracers keep the whole batch in `val` (a concrete array when not under jit)
        if not hasattr(x, "batch_dim") or not hasattr(x, "val"):
            return None
        x = x.val
    return np.asarray(x)


def _show(value: np.ndarray, bad: np.ndarray) -> str:
    """The offending values, in full when few, else a count and a sample."""
    if value.size <= 8:
        return str(value.tolist())
    return f"with {int(bad.sum())} of {value.size} values invalid, e.g. {value[bad][:5].tolist()},"


@dataclass(frozen=True)
class Discrete:
    """Integer actions `0 .. n - 1` (scalar)."""

    n: int
    shape: tuple[int, ...] = ()
    dtype: Any = jnp.int32

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, self.shape, 0, self.n, dtype=self.dtype)

    def contains(self, x: Any) -> bool:
        x = np.asarray(x)
        return x.shape == self.shape and np.issubdtype(x.dtype, np.integer) and bool(
            np.all((x >= 0) & (x < self.n))
        )

    def check(self, x: Any, what: str = "action") -> None:
        """Raise `ValueError`/`TypeError` if `x` is not an element of this space."""
        shape, dtype = jnp.shape(x), jnp.result_type(x)
        if shape != self.shape:
            raise ValueError(
                f"{what} has shape {shape}; expected shape {self.shape} (one integer in 0..{self.n - 1})"
            )
        if not jnp.issubdtype(dtype, jnp.integer):
            raise TypeError(
                f"{what} has dtype {dtype}; expected an integer dtype for Discrete({self.n})"
            )
        value = _concrete_value(x)
        if value is not None:
            bad = (value < 0) | (value >= self.n)
            if np.any(bad):
                raise ValueError(
                    f"{what} {_show(value, bad)} is out of range; accepted values are "
                    f"0..{self.n - 1}"
                )

    def is_valid(self, x: jax.Array) -> jax.Array:
        """bool[]: every entry of `x` in 0..n-1 (traceable; one unsigned compare per entry)."""
        return jnp.all(x.astype(jnp.uint32) < self.n)

    def sanitize(self, x: jax.Array, valid: jax.Array) -> jax.Array:
        """`x` where `valid`, else action 0 (traceable)."""
        return jnp.where(valid, x, jnp.zeros_like(x))


@dataclass(frozen=True)
class Box:
    """Arrays of a fixed shape with elementwise bounds `low <= x <= high`."""

    low: float
    high: float
    shape: tuple[int, ...]
    dtype: Any = jnp.float32

    def sample(self, key: jax.Array) -> jax.Array:
        if jnp.issubdtype(self.dtype, jnp.integer):
            return jax.random.randint(key, self.shape, self.low, self.high + 1, dtype=self.dtype)
        return jax.random.uniform(key, self.shape, self.dtype, self.low, self.high)

    def contains(self, x: Any) -> bool:
        x = np.asarray(x)
        return (
            x.shape == self.shape
            and np.can_cast(x.dtype, self.dtype, casting="same_kind")
            and bool(np.all((x >= self.low) & (x <= self.high)))
        )

    def check(self, x: Any, what: str = "action") -> None:
        """Raise if `x` has the wrong shape or dtype, or (when concrete) holds NaN/inf."""
        shape, dtype = jnp.shape(x), jnp.result_type(x)
        if shape != self.shape:
            raise ValueError(f"{what} has shape {shape}; expected shape {self.shape}")
        if not jnp.issubdtype(dtype, jnp.floating):
            raise TypeError(f"{what} has dtype {dtype}; expected a floating dtype")
        value = _concrete_value(x)
        if value is not None and not np.all(np.isfinite(value)):
            raise ValueError(
                f"{what} {_show(value, ~np.isfinite(value))} contains NaN or inf; accepted: "
                f"finite values (clipped to [{self.low}, {self.high}])"
            )

    def is_valid(self, x: jax.Array) -> jax.Array:
        """bool[]: every entry of `x` finite (traceable; integer arrays are always valid)."""
        if not jnp.issubdtype(jnp.result_type(x), jnp.inexact):
            return jnp.asarray(True)
        return jnp.all(jnp.isfinite(x))

    def sanitize(self, x: jax.Array, valid: jax.Array) -> jax.Array:
        """`x` where `valid`, else zeros (traceable)."""
        return jnp.where(valid, x, jnp.zeros_like(x))


@dataclass(frozen=True)
class Dict:
    """A mapping of named spaces (observations)."""

    spaces: Mapping[str, Any]

    def __getitem__(self, name: str) -> Any:
        return self.spaces[name]

    def sample(self, key: jax.Array) -> dict[str, jax.Array]:
        keys = jax.random.split(key, len(self.spaces))
        return {name: space.sample(k) for (name, space), k in zip(self.spaces.items(), keys)}

    def contains(self, x: Mapping[str, Any]) -> bool:
        return set(x) == set(self.spaces) and all(
            space.contains(x[name]) for name, space in self.spaces.items()
        )
