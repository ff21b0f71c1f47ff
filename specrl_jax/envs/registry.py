"""Env IDs -> constructors. Variants are registry entries over configs, never subclasses."""

from __future__ import annotations

import difflib
from collections.abc import Callable
from typing import Any

_REGISTRY: dict[str, tuple[Callable[..., tuple[Any, Any]], str]] = {}


def register(env_id: str, factory: Callable[..., tuple[Any, Any]], description: str = "") -> None:
    """Register `factory(**overrides) -> (env, params)` under `env_id`."""
    if env_id in _REGISTRY:
        raise ValueError(f"env ID {env_id!r} is already registered")
    _REGISTRY[env_id] = (factory, description)


def list_envs() -> list[str]:
    """All registered env IDs, sorted."""
    _load_worlds()
    return sorted(_REGISTRY)


def describe(env_id: str) -> str:
    _load_worlds()
    return _REGISTRY[_checked_id(env_id)][1]


def make(env_id: str, **overrides: Any) -> tuple[Any, Any]:
    """Build `(env, params)` for a registered ID; `overrides` change config or params fields."""
    _load_worlds()
    factory, _ = _REGISTRY[_checked_id(env_id)]
    return factory(**overrides)


def _checked_id(env_id: str) -> str:
    if not isinstance(env_id, str):
        raise TypeError(f"env ID must be a string, got {type(env_id).__name__}")
    if env_id not in _REGISTRY:
        close = difflib.get_close_matches(env_id, list(_REGISTRY), n=3, cutoff=0.6)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        raise ValueError(
            f"unknown env ID {env_id!r}.{hint} Known IDs: {', '.join(sorted(_REGISTRY))}"
        )
    return env_id


def _load_worlds() -> None:
    """Import the world modules so that they register their IDs (idempotent)."""
    import specrl_jax.envs.letter

    try:
        import specrl_jax.envs.zone  # noqa: F401
    except ModuleNotFoundError as err:  # the zone world is optional until it lands
        if err.name != "specrl_jax.envs.zone":
            raise
