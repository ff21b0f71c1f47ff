"""Checked mode: run an env (or a `BatchedEnv` of one) so that invalid input raises.

`checked(env)` returns an env whose `reset` and `step` raise where the plain env only flags the
problem: an action outside the action space inside a trace or a batch (the plain step sets
`info["invalid_action"]`, ends the episode and steps with `action_space.sanitize(action)`), or
a layout sampler that ran out of rounds (the plain reset falls back to a fixed valid layout).

A single env runs under `jax.experimental.checkify` (user checks: `checkify.JaxRuntimeError`).
A `BatchedEnv` is stepped as usual and its `info["invalid_action"]` read on the host
(`ValueError` naming the worlds): checkify cannot transform a batched while loop, which every
layout sampler is. Each call is jitted once per instance; keep this mode for debugging.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.experimental import checkify

from specrl_jax.envs.base import Obs, StepOut, check_action_container, checking
from specrl_jax.envs.wrappers import BatchedEnv


class Checked:
    """`env` with its invalid-input flags turned into exceptions."""

    def __init__(self, env: Any):
        self.env = env
        self._batched = isinstance(env, BatchedEnv)
        if self._batched:
            self._reset, self._step = jax.jit(env.reset), jax.jit(env.step)
        else:
            space = env.action_space

            def step(key: jax.Array, state: Any, action: jax.Array, params: Any) -> StepOut:
                out = env.step(key, state, action, params)
                message = f"invalid action {{a}}; accepted: elements of {space}"
                checkify.check(~out[5]["invalid_action"], message, a=action)
                return out

            self._reset = jax.jit(checkify.checkify(env.reset, errors=checkify.user_checks))
            self._step = jax.jit(checkify.checkify(step, errors=checkify.user_checks))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def reset(self, key: jax.Array, params: Any = None) -> tuple[Obs, Any]:
        params = self.env.default_params if params is None else params
        if self._batched:
            return self._reset(key, params)
        with checking():  # traced here, the layout samplers' checks (`base.sampler_check`)
            error, out = self._reset(key, params)
        error.throw()
        return out

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None) -> StepOut:
        params = self.env.default_params if params is None else params
        space = self.env.action_space
        shape = (self.env.num_envs, *space.shape) if self._batched else space.shape
        check_action_container(action, shape, space.dtype, "batched action" if self._batched
                               else "action")
        if not self._batched:
            error, out = self._step(key, state, action, params)
            error.throw()
            return out
        out = self._step(key, state, action, params)
        invalid = np.asarray(out[5]["invalid_action"])
        if invalid.any():
            worlds = np.flatnonzero(invalid)
            raise ValueError(
                f"invalid actions in {worlds.size} of {invalid.size} worlds (indices "
                f"{worlds[:8].tolist()}), e.g. {np.asarray(action)[worlds[:3]].tolist()}; "
                f"accepted: elements of {self.env.action_space}"
            )
        return out

    def __repr__(self) -> str:
        return f"checked({self.env!r})"


def checked(env: Any) -> Checked:
    """`env` in checked mode: invalid actions and exhausted layout samplers raise."""
    return Checked(env)
