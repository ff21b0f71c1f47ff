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
"""

from __future__ import annotations

import abc
from typing import Any

import jax

Obs = dict[str, jax.Array]
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
        return self.reset_env(key, self.default_params if params is None else params)

    def step(
        self, key: jax.Array, state: Any, action: jax.Array, params: Any | None = None
    ) -> StepOut:
        """Validate `action` (shape and dtype always, values when concrete), then step."""
        params = self.default_params if params is None else params
        self.action_space.check(action)
        obs, state, reward, terminated, info = self.step_env(key, state, action, params)
        truncated = (state.time >= params.max_steps) & ~terminated
        return obs, state, reward, terminated, truncated, info

    def __repr__(self) -> str:
        return f"{type(self).__name__}({getattr(self, 'config', '')})"

