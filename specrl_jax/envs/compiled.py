"""Compiled functions shared by every world of one type and config: an env is its frozen config
plus pure functions, so two envs of one config can run one compiled program. The one
process-wide cache of such programs (eager `reset`/`step`, the Gymnasium bridges)."""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any, TypeVar

T = TypeVar("T")

#: (kind, env type, config) -> what `build` made for it
_SHARED: dict[Any, Any] = {}


def config_key(env: Any) -> Hashable | None:
    """`(type(env), env.config)` when the world has a hashable config, else None."""
    try:
        key = (type(env), env.config)
        hash(key)
    except (AttributeError, TypeError):
        return None
    return key


def shared(env: Any, kind: Hashable, build: Callable[[], T]) -> T:
    """`build()` made once per `kind` and world type and config (once per env instance for a
    world without a hashable config)."""
    key = config_key(env)
    if key is None:
        own = env.__dict__.setdefault("_shared_compiled", {})
        if kind not in own:
            own[kind] = build()
        return own[kind]
    if (kind, key) not in _SHARED:
        _SHARED[(kind, key)] = build()
    return _SHARED[(kind, key)]
