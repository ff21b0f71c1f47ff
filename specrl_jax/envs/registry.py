"""Env IDs -> constructors, as one explicit table. Importing a world module registers nothing:
each world family exposes `env_ids() -> {env_id: (factory, description)}`, and the table below
lists the families. Variants are entries over configs, never subclasses."""

from __future__ import annotations

import difflib
import functools
import importlib
from collections.abc import Callable
from typing import Any

Factory = Callable[..., tuple[Any, Any]]

#: world families: module path of each family's `env_ids()`, in listing order
FAMILIES: tuple[str, ...] = (
    "specrl_jax.envs.letter",
    "specrl_jax.envs.zone",
    "specrl_jax.envs.arm",
    "specrl_jax.envs.multi",
)

_EXTRA: dict[str, tuple[Factory, str]] = {}


@functools.cache
def _family_table() -> dict[str, tuple[Factory, str]]:
    table: dict[str, tuple[Factory, str]] = {}
    for module in FAMILIES:
        for env_id, entry in importlib.import_module(module).env_ids().items():
            if env_id in table:
                raise RuntimeError(f"env ID {env_id!r} is declared by two families")
            table[env_id] = entry
    return table


def _table() -> dict[str, tuple[Factory, str]]:
    return {**_family_table(), **_EXTRA}


def register(env_id: str, factory: Factory, description: str = "") -> None:
    """Add a user's own `factory(**overrides) -> (env, params)` under `env_id`."""
    if env_id in _table():
        raise ValueError(f"env ID {env_id!r} is already registered")
    _EXTRA[env_id] = (factory, description)


def list_envs() -> list[str]:
    """All registered env IDs, sorted."""
    return sorted(_table())


def describe(env_id: str) -> str:
    return _table()[_checked_id(env_id)][1]


def make(env_id: str, **overrides: Any) -> tuple[Any, Any]:
    """Build `(env, params)` for a registered ID; `overrides` change config or params fields."""
    factory, _ = _table()[_checked_id(env_id)]
    return factory(**overrides)


def _checked_id(env_id: str) -> str:
    if not isinstance(env_id, str):
        raise TypeError(f"env ID must be a string, got {type(env_id).__name__}")
    table = _table()
    if env_id not in table:
        close = difflib.get_close_matches(env_id, list(table), n=3, cutoff=0.6)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        raise ValueError(
            f"unknown env ID {env_id!r}.{hint} Known IDs: {', '.join(sorted(table))}"
        )
    return env_id
