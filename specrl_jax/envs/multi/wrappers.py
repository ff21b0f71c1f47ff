"""Same-step auto-reset for a multi-agent world, whose termination flags are per agent."""

from __future__ import annotations

from typing import Any

import jax

from specrl_jax.envs.base import StepOut
from specrl_jax.envs.wrappers import Wrapper, reset_done


class MultiAutoReset(Wrapper):
    """`envs.wrappers.AutoReset` for per-agent flags: when the world's episode ends
    (`env.episode_done(terminated, truncated)`: every agent done), the returned obs and state
    are a fresh episode's (a new layout); `info["final_observation"]` keeps the last one,
    `info["final_info"]` that step's info and `info["episode_done"]` (bool[]) marks the step.
    `terminated`/`truncated` (bool[N]) and the labels describe the step that was taken."""

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None) -> StepOut:
        params = self.env.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, state_next, reward, terminated, truncated, info = self.env.step(
            key_step, state, action, params
        )
        done = self.env.episode_done(terminated, truncated)
        info = {**info, "final_info": dict(info), "episode_done": done}
        obs, state_next, info = reset_done(
            done, lambda: self.env.reset(key_reset, params), obs, state_next, info
        )
        return obs, state_next, reward, terminated, truncated, info
