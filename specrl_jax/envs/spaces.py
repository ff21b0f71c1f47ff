"""Observation and action spaces, with the checks done at the Python boundary.

Shape and dtype checks are static, so they also run while tracing under `jit`/`vmap`;
value checks (range, NaN) run only on concrete arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def _is_concrete(x: Any) -> bool:
    return not isinstance(x, jax.core.Tracer)


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
        if _is_concrete(x):
            value = np.asarray(x)
            if np.any((value < 0) | (value >= self.n)):
                raise ValueError(
                    f"{what} {value.tolist()} is out of range; accepted values are 0..{self.n - 1}"
                )


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
        if _is_concrete(x) and not np.all(np.isfinite(np.asarray(x))):
            raise ValueError(f"{what} contains NaN or inf: {np.asarray(x).tolist()}")


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
