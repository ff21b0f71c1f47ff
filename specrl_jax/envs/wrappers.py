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

from specrl_jax.envs.base import Obs, StepOut, check_action_container


def select_tree(pred: jax.Array, on_true: Any, on_false: Any) -> Any:
    """Leaf-wise `where(pred, on_true, on_false)`; `pred` is bool[] (one env) or bool[B] (a
    batch: broadcast over each leaf's trailing axes)."""

    def pick(a: jax.Array, b: jax.Array) -> jax.Array:
        return jnp.where(jnp.reshape(pred, jnp.shape(pred) + (1,) * (jnp.ndim(b) - jnp.ndim(pred))),
                         a, b)

    return jax.tree.map(pick, on_true, on_false)


def episode_done(env: Any, terminated: jax.Array, truncated: jax.Array) -> jax.Array:
    """bool[]: one world's episode is over. A world with per-agent flags (`terminated bool[N]`)
    defines it as `env.episode_done` (a multi-agent Zone world: every agent done); otherwise
    `terminated | truncated`."""
    done = terminated | truncated
    if jnp.ndim(done) == 0:
        return done
    return env.episode_done(terminated, truncated) if hasattr(env, "episode_done") else jnp.all(done)


def reset_done(done: jax.Array, reset: Callable[[jax.Array], tuple[Obs, Any]], key: jax.Array,
               obs: Any, state: Any, info: dict[str, Any],
               resets_per_step: int | None = None) -> tuple[Any, Any, dict[str, Any]]:
    """The project's one auto-reset (same step): where `done`, the obs and state of a fresh
    episode replace the stepped ones; `info["final_observation"]` keeps the stepped observation
    (the last one of a finished episode). Every reset is a fresh draw (never a cached state).

    Args:
        done: bool[] for one world, or bool[B] for a batch (obs and state with leading axis B).
        reset: `key -> (obs, state)`, one fresh episode of one world.
        key: the resets' key.
        resets_per_step: a batch's number k of fresh resets computed per step (default: B, a
            reset for every world). With k < B the k resets are scattered into the worlds that
            finished; a step where more than k finish falls back to a reset for every world
            (`lax.cond`; under an outer `vmap` both branches run). This is the fast form where
            resets are costly: an exact reset (e.g. a rejection-sampled LetterWorld map) under
            `vmap` costs as much as its slowest lane, so computing B per step made `batch(env,
            256)` ~50x slower. Results equal those of k = B up to which fresh draw a world gets.
    """
    info = {**info, "final_observation": obs}
    if jnp.ndim(done) == 0:
        obs_reset, state_reset = reset(key)
        return select_tree(done, obs_reset, obs), select_tree(done, state_reset, state), info
    num = done.shape[0]
    k = num if resets_per_step is None else resets_per_step
    reset_many = jax.vmap(reset)

    def reset_all(_: None) -> tuple[Any, Any]:
        return select_tree(done, reset_many(jax.random.split(key, num)), (obs, state))

    def scatter_few(_: None) -> tuple[Any, Any]:
        (index,) = jnp.nonzero(done, size=k, fill_value=num)  # past the end: dropped
        fresh = reset_many(jax.random.split(key, k))
        return jax.tree.map(lambda x, r: x.at[index].set(r, mode="drop"), (obs, state), fresh)

    if k >= num:
        new_obs, new_state = reset_all(None)
    else:
        new_obs, new_state = jax.lax.cond(jnp.sum(done) <= k, scatter_few, reset_all, None)
    return new_obs, new_state, info


class Wrapper:
    """Forwards every attribute it does not define to the wrapped env."""

    def __init__(self, env: Any):
        self.env = env

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.env!r})"


class AutoReset(Wrapper):
    """Same-step auto-reset (`reset_done`): when an episode ends (`episode_done`), the returned
    obs and state are those of a fresh episode (a new layout); the last observation of the
    finished episode is kept in `info["final_observation"]`, and `info["final_info"]` keeps that
    step's info. A world with per-agent flags (`terminated bool[N]`) ends its episode when
    every agent is done, marked by `info["episode_done"]` (bool[]).

    `terminated`/`truncated` and `info["propositions"]` describe the step that was taken.
    """

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None) -> StepOut:
        params = self.env.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, state_next, reward, terminated, truncated, info = self.env.step(
            key_step, state, action, params
        )
        done = episode_done(self.env, terminated, truncated)
        info = {**info, "final_info": dict(info)}
        if jnp.ndim(terminated) > 0:  # per-agent flags
            info["episode_done"] = done
        obs, state_next, info = reset_done(
            done, lambda k: self.env.reset(k, params), key_reset, obs, state_next, info
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
        space = self.env.action_space
        expected = (self.num_envs, *space.shape)
        check_action_container(action, expected, space.dtype, "batched action")
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
    `info["final_observation"]` and `info["final_info"]`; a world with per-agent flags ends its
    episode as `AutoReset` says (`episode_done`: every agent done), marked by
    `info["episode_done"]` (bool[B]). Cost differs: `reset_done` computes `resets_per_step`
    (default B / 32) fresh resets per step and scatters them into the worlds that finished
    (a reset for every world on a step where more finish).
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
        done = jax.vmap(lambda te, tr: episode_done(self.env, te, tr))(terminated, truncated)
        info = {**info, "final_info": dict(info)}
        if jnp.ndim(terminated) > 1:  # per-agent flags
            info["episode_done"] = done
        obs, state, info = reset_done(done, lambda k: self.env.reset(k, params), key_reset, obs,
                                      state, info, self.resets_per_step)
        return obs, state, reward, terminated, truncated, info


def batch(env: Any, num_envs: int, auto_reset: bool = True,
          resets_per_step: int | None = None) -> BatchedEnv:
    """The one-liner for mass simulation: `num_envs` auto-resetting copies of `env` (resets
    computed for the finished worlds only, see `BatchedAutoReset`)."""
    if not auto_reset:
        return BatchedEnv(env, num_envs)
    return BatchedAutoReset(env, num_envs, resets_per_step)
