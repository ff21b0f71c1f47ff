"""The functional environment contract shared by every world.

An env is a frozen, hashable config (static shapes) plus pure functions:

    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

`params` carries values that may vary without changing shapes (so they `vmap`); every state
has an int32 `time` field; the horizon `params.max_steps` sets `truncated`. The world's own
terminations are `terminated`. `info["propositions"]` is `bool[P]` in the order of
`env.propositions`, the labelling function after the step. An env that can name the row of
`env.alphabet` equal to that label without a lookup also reports it as `info["symbol"]` (int32);
the task layer passes it to the automaton step (`automata.step_in_batch`), which then skips its
label lookup.

Invalid actions have one defined behaviour on every path. Called eagerly (concrete arrays, also
the batch of an eager `vmap`), `step` raises `ValueError`. Traced (under `jit`/`vmap`), an action
outside the action space (a discrete action out of range, a continuous one holding NaN or inf)
is replaced by `action_space.sanitize` (action 0, or zeros), the episode ends (`terminated`),
and `info["invalid_action"]` (bool) is set; it is False on every valid step, so wrappers pass
it on. `checked(env)` (`envs/checked.py`) raises instead. (No check is traced into the step
itself: even a `checkify.debug_check` made LetterWorld's batched CPU step 35% slower.)
An action given as a Python list or tuple (e.g. of traced values, built inside a trace) is
refused with `TypeError` naming the accepted shape and dtype: an action is one array.

Eager `reset`/`step` calls (outside any trace) run a jitted function shared by every env of the
same type and config, so a second env of one config compiles nothing.
"""

from __future__ import annotations

import abc
import contextlib
import contextvars
from collections.abc import Iterator
from typing import Any

import jax
import jax.numpy as jnp
from jax.experimental import checkify

from specrl_jax.envs import compiled

Obs = dict[str, jax.Array]

_CHECKING = contextvars.ContextVar("specrl_jax_checking", default=False)


@contextlib.contextmanager
def checking() -> Iterator[None]:
    """Traces inside it are checked mode's (`envs.checked`): `sampler_check` becomes a user check
    for `jax.experimental.checkify`."""
    token = _CHECKING.set(True)
    try:
        yield
    finally:
        _CHECKING.reset(token)


def sampler_check(ok: jax.Array, message: str) -> None:
    """A layout sampler's failure (`ok` False: it gave up and fell back) raised as `message` in
    checked mode, and nothing elsewhere. (A `checkify.debug_check` would trace a process-wide
    error counter into every program that resets a world, so that one program traced after
    another check would miss the persistent compilation cache.)"""
    if _CHECKING.get():
        checkify.check(ok, message)

Info = dict[str, Any]
StepOut = tuple[Obs, Any, jax.Array, jax.Array, jax.Array, Info]

#: kinds of observation parts; a method picks its encoder for `obs[key]` by `env.obs_kinds[key]`:
#: "grid" (uint8[V, V, C] cell channels, proposition channels last for "ap"), "lidar"
#: (float32[P, R] bins per proposition), "range_bearing" (float32[P, ..., 4]), "image"
#: (uint8[H, W, 3] camera pixels), "vector" (float32[E], robot sensors)
OBS_KINDS = ("grid", "lidar", "range_bearing", "image", "vector")


class Env(abc.ABC):
    """Base class: subclasses implement `reset_env`, `step_env`, `layout`, `reset_to`."""

    #: proposition names, in the order of `info["propositions"]` and `obs["ap"]`'s proposition axis.
    propositions: tuple[str, ...]

    #: observation key -> its kind (one of `OBS_KINDS`); `ap` is the proposition-dependent part
    obs_kinds: dict[str, str]

    #: the name of the world's family record (`specrl_jax.families`): horizon, suites, settings
    family: str

    @property
    @abc.abstractmethod
    def default_params(self) -> Any:
        """Default `EnvParams` (must have an int `max_steps` field)."""

    @property
    @abc.abstractmethod
    def action_space(self) -> Any: ...

    @property
    @abc.abstractmethod
    def observation_space(self) -> Any: ...

    @property
    @abc.abstractmethod
    def alphabet(self) -> jax.Array:
        """`bool[A, P]`: every proposition assignment the world can produce."""

    @property
    def num_propositions(self) -> int:
        return len(self.propositions)

    @abc.abstractmethod
    def reset_env(self, key: jax.Array, params: Any) -> tuple[Obs, Any]: ...

    @abc.abstractmethod
    def step_env(
        self, key: jax.Array, state: Any, action: jax.Array, params: Any
    ) -> tuple[Obs, Any, jax.Array, jax.Array, Info]:
        """One world step: returns `(obs, state, reward, terminated, info)`; time is advanced here."""

    @abc.abstractmethod
    def layout(self, state: Any) -> dict[str, jax.Array]:
        """The world's geometry as a dict of arrays (see each env's docstring)."""

    @abc.abstractmethod
    def reset_to(self, key: jax.Array, layout: dict[str, Any], params: Any) -> tuple[Obs, Any]:
        """Start an episode from a given geometry (as returned by `layout`)."""

    def reset(self, key: jax.Array, params: Any | None = None) -> tuple[Obs, Any]:
        """Start a new episode with a freshly sampled layout."""
        params = self.default_params if params is None else params
        if not _is_traced((key, params)):
            return _compiled(self).reset(key, params)
        return self.reset_env(key, params)

    def step(
        self, key: jax.Array, state: Any, action: jax.Array, params: Any | None = None
    ) -> StepOut:
        """Validate `action` (shape and dtype always, values when concrete), then step.

        `info["invalid_action"]` (bool) marks a traced step whose action was outside the action
        space; that step used `action_space.sanitize(action)` and ends the episode (`terminated`).
        """
        params = self.default_params if params is None else params
        space = self.action_space
        check_action_container(action, space.shape, space.dtype)
        space.check(action)
        if not _is_traced((key, state, action, params)):
            # one dtype for Python scalars and arrays alike, so both hit one compiled step
            action = jnp.asarray(action, space.dtype)
            return _compiled(self).step(key, state, action, params)
        valid = space.is_valid(action)
        obs, state, reward, terminated, info = self.step_env(
            key, state, space.sanitize(action, valid), params
        )
        terminated = terminated | ~valid
        truncated = (state.time >= params.max_steps) & ~terminated
        info = {**info, "invalid_action": ~valid}
        return obs, state, reward, terminated, truncated, info

    def __repr__(self) -> str:
        return f"{type(self).__name__}({getattr(self, 'config', '')})"


def check_action_container(action: Any, shape: tuple[int, ...], dtype: Any,
                           what: str = "action") -> None:
    """Raise `TypeError` for an action given as a Python list or tuple: an action is one array
    (under `jit` a list of traced values cannot be read as one, and JAX would raise
    `TracerArrayConversionError` from inside the shape check)."""
    if isinstance(action, (list, tuple)):
        traced = " holding traced values (built under jit/vmap)" if _is_traced(action) else ""
        raise TypeError(
            f"{what} is a Python {type(action).__name__} of {len(action)} items{traced}; "
            f"expected one array of shape {tuple(shape)} and dtype {jnp.dtype(dtype).name} "
            "(pass jnp.asarray(...) or jnp.stack(...) of it)"
        )


def _is_traced(tree: Any) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


class _Compiled:
    """Jitted `reset` and `step` of one env, run when they are called outside a trace."""

    def __init__(self, env: Env):
        self.reset = jax.jit(env.reset)
        self.step = jax.jit(env.step)


def _compiled(env: Env) -> _Compiled:
    """The compiled functions of `env`'s type and config (per instance without a hashable config)."""
    return compiled.shared(env, "eager", lambda: _Compiled(env))
