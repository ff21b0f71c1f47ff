"""Wrappers over the functional env contract: auto-reset, episode statistics, batching.

Each wrapper is itself an env with the same `reset`/`step` signatures, so they compose:
`BatchedEnv(EpisodeStatistics(AutoReset(env)), num_envs=4096)`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from specrl_jax.envs.base import Obs, StepOut


def select_tree(pred: jax.Array, on_true: Any, on_false: Any) -> Any:
    """Leaf-wise `where(pred, on_true, on_false)` for a scalar `pred` (one env)."""
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


def reset_done(done: jax.Array, reset: Callable[[], tuple[Obs, Any]], obs: Any, state: Any,
               info: dict[str, Any]) -> tuple[Any, Any, dict[str, Any]]:
    """The project's one auto-reset (same step, one env): where `done`, the obs and state of a
    fresh episode from `reset()` replace the stepped ones; `info["final_observation"]` keeps the
    last observation of the finished episode. Every reset is a fresh draw (never a cached state).
    """
    obs_reset, state_reset = reset()
    info = {**info, "final_observation": obs}
    return select_tree(done, obs_reset, obs), select_tree(done, state_reset, state), info


class Wrapper:
    """Forwards every attribute it does not define to the wrapped env."""

    def __init__(self, env: Any):
        self.env = env

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.env!r})"


class AutoReset(Wrapper):
    """Same-step auto-reset: when an episode ends, the returned obs and state are those of a
    fresh episode (a new layout); the last observation of the finished episode is kept in
    `info["final_observation"]`, and `info["final_info"]` keeps that step's info.

    `terminated`/`truncated` and `info["propositions"]` describe the step that was taken.
    """

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None) -> StepOut:
        params = self.env.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, state_next, reward, terminated, truncated, info = self.env.step(
            key_step, state, action, params
        )
        obs, state_next, info = reset_done(
            terminated | truncated, lambda: self.env.reset(key_reset, params), obs, state_next,
            {**info, "final_info": dict(info)},
        )
        return obs, state_next, reward, terminated, truncated, info


@struct.dataclass
class EpisodeStatsState:
    env_state: Any
    episode_return: jax.Array  # float32, running return of the current episode
    episode_length: jax.Array  # int32, steps so far in the current episode
    returned_episode_return: jax.Array  # float32, return of the last finished episode
    returned_episode_length: jax.Array  # int32, length of the last finished episode

    @property
    def time(self) -> jax.Array:
        return self.env_state.time


class EpisodeStatistics(Wrapper):
    """Tracks episode return and length; `info["episode_return"]`/`["episode_length"]` hold the
    values of the last finished episode and `info["returned_episode"]` marks steps that end one."""

    def reset(self, key: jax.Array, params: Any = None) -> tuple[Obs, EpisodeStatsState]:
        obs, env_state = self.env.reset(key, params)
        zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
        return obs, EpisodeStatsState(env_state, zero_f, zero_i, zero_f, zero_i)

    def step(
        self, key: jax.Array, state: EpisodeStatsState, action: jax.Array, params: Any = None
    ) -> StepOut:
        obs, env_state, reward, terminated, truncated, info = self.env.step(
            key, state.env_state, action, params
        )
        done = terminated | truncated
        episode_return = state.episode_return + reward
        episode_length = state.episode_length + 1
        new_state = EpisodeStatsState(
            env_state=env_state,
            episode_return=jnp.where(done, 0.0, episode_return),
            episode_length=jnp.where(done, 0, episode_length),
            returned_episode_return=jnp.where(done, episode_return, state.returned_episode_return),
            returned_episode_length=jnp.where(done, episode_length, state.returned_episode_length),
        )
        info = dict(info)
        info["returned_episode"] = done
        info["episode_return"] = new_state.returned_episode_return
        info["episode_length"] = new_state.returned_episode_length
        return obs, new_state, reward, terminated, truncated, info


class BatchedEnv(Wrapper):
    """`num_envs` copies of an env stepped by one `vmap`; keys are split per env, params shared.

    `reset(key)` returns obs and state with a leading axis `B = num_envs`; `step` takes actions
    of shape `[B, ...]`.
    """

    def __init__(self, env: Any, num_envs: int):
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        super().__init__(env)
        self.num_envs = num_envs

    def reset(self, key: jax.Array, params: Any = None) -> tuple[Obs, Any]:
        params = self.env.default_params if params is None else params
        keys = jax.random.split(key, self.num_envs)
        return jax.vmap(self.env.reset, in_axes=(0, None))(keys, params)

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None) -> StepOut:
        params = self.env.default_params if params is None else params
        expected = (self.num_envs, *self.env.action_space.shape)
        if jnp.shape(action) != expected:
            raise ValueError(
                f"batched action has shape {jnp.shape(action)}; expected {expected} "
                f"(num_envs={self.num_envs} x the action shape {self.env.action_space.shape})"
            )
        keys = jax.random.split(key, self.num_envs)
        return jax.vmap(self.env.step, in_axes=(0, 0, 0, None))(keys, state, action, params)

    def sample_actions(self, key: jax.Array) -> jax.Array:
        """Uniformly random actions, `[B, ...]`."""
        keys = jax.random.split(key, self.num_envs)
        return jax.vmap(self.env.action_space.sample)(keys)


class BatchedAutoReset(BatchedEnv):
    """`num_envs` copies of an env, auto-resetting, with resets computed for finished worlds only.

    Semantics are `BatchedEnv(AutoReset(env))`'s: the same step, every reset a fresh exact draw,
    `info["final_observation"]` and `info["final_info"]`. Cost differs: an exact reset (e.g. a
    rejection-sampled LetterWorld map) under `vmap` costs as much as its slowest lane, and the
    plain wrapper computes one per world at every step. Here a step computes `resets_per_step`
    (default B / 32) fresh resets and scatters them into the worlds that finished; a step where
    more worlds finish falls back to a reset for every world (`lax.cond`; under an outer `vmap`
    both branches run).
    """

    def __init__(self, env: Any, num_envs: int, resets_per_step: int | None = None):
        super().__init__(env, num_envs)
        k = max(1, num_envs // 32) if resets_per_step is None else resets_per_step
        if not isinstance(k, int) or not 1 <= k <= num_envs:
            raise ValueError(f"resets_per_step must be an int in 1..{num_envs}, got {k!r}")
        self.resets_per_step = k

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None) -> StepOut:
        params = self.env.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, state, reward, terminated, truncated, info = super().step(
            key_step, state, action, params)
        done = terminated | truncated
        info = {**info, "final_info": dict(info)}
        reset = jax.vmap(self.env.reset, in_axes=(0, None))
        num, k = self.num_envs, self.resets_per_step

        def scatter_few(_):
            (index,) = jnp.nonzero(done, size=k, fill_value=num)  # past the end: dropped
            fresh = reset(jax.random.split(key_reset, k), params)
            return jax.tree.map(lambda x, r: x.at[index].set(r, mode="drop"), (obs, state), fresh)

        def reset_all(_):
            fresh = reset(jax.random.split(key_reset, num), params)
            return jax.tree.map(lambda r, x: jnp.where(done.reshape(-1, *[1] * (x.ndim - 1)), r, x),
                                fresh, (obs, state))

        new_obs, new_state = jax.lax.cond(jnp.sum(done) <= k, scatter_few, reset_all, None)
        info["final_observation"] = obs
        return new_obs, new_state, reward, terminated, truncated, info


def batch(env: Any, num_envs: int, auto_reset: bool = True,
          resets_per_step: int | None = None) -> BatchedEnv:
    """The one-liner for mass simulation: `num_envs` auto-resetting copies of `env` (resets
    computed for the finished worlds only, see `BatchedAutoReset`)."""
    if not auto_reset:
        return BatchedEnv(env, num_envs)
    return BatchedAutoReset(env, num_envs, resets_per_step)
