"""Compiled functions shared by every world of one type and config: an env is its frozen config
plus pure functions, so two envs of one config can run one compiled program. The one
process-wide cache of such programs (eager `reset`/`step`, the Gymnasium bridges), and the key
(`ByKey`) under which the MJX physics share their traces."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import numpy as np

if TYPE_CHECKING:
    import mujoco

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


def model_digest(model: mujoco.MjModel) -> str:
    """SHA-256 of `model`'s binary form: equal for models compiled from one MJCF."""
    import mujoco  # this module is on the light import path (the Gymnasium bridge, env listing)

    buffer = np.empty(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return hashlib.sha256(buffer.tobytes()).hexdigest()


class ByKey(Generic[T]):
    """`value` as a static `jax.jit` argument, equal to any `ByKey` of an equal `key`.

    JAX keeps the jaxpr of a jitted function per static arguments and argument shapes, and
    reuses it wherever the function is called again, inside any other `jit`, `vmap` or
    `eval_shape`; XLA inlines the nested call, so the compiled program is unchanged. A jitted
    function that takes the physics as `ByKey(key, physics)`, `key` naming all that its trace
    reads, therefore traces MuJoCo's pipeline once per model and options in a process, not
    once per env, call site and reset path.
    """

    __slots__ = ("key", "value")

    def __init__(self, key: Hashable, value: T):
        self.key = key
        self.value = value

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ByKey) and self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)
