"""Collecting experience: the training-env contract a method provides and the rollout scan.

A method's training env is functional and unbatched (the trainer `vmap`s it) and resets itself:
  `reset(key, task_params) -> (obs, state)`
  `step(key, state, action, task_params) -> (obs, state, StepResult)`
where `obs` is what the method's network reads and `task_params` is the method's trainer-carried
task distribution (e.g. a curriculum stage), or `None`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp

from specrl_jax.baselines.ppo.networks import PolicyOutput


class StepResult(NamedTuple):
    """One training-env step (scalars for one env).

    `terminated`: the episode ended (no bootstrap); `truncated`: the horizon ended it; `cut`: the
    episode goes on but the return is cut here (GenZ's subgoal switch); `final_obs`: the obs
    before the auto-reset (read only to bootstrap time-outs that are not terminal);
    `stats`: float32 scalars summed over the rollout (e.g. `episodes`, `successes`).
    """

    reward: jax.Array
    cost: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    cut: jax.Array
    final_obs: Any
    stats: dict[str, jax.Array]


class TrainEnv(Protocol):
    def reset(self, key: jax.Array, task_params: Any) -> tuple[Any, Any]: ...

    def step(self, key: jax.Array, state: Any, action: jax.Array, task_params: Any) -> tuple[Any, Any, StepResult]: ...


class Transition(NamedTuple):
    """One rollout step for all envs; stacked by `scan` to `[T, B, ...]`."""

    obs: Any
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    cost_value: jax.Array
    reward: jax.Array
    cost: jax.Array
    done: jax.Array  # bool: no bootstrap from the next step (terminated | cut | time-out if terminal)
    stats: dict[str, jax.Array]


ApplyFn = Callable[[Any, Any], PolicyOutput]


def reset_batch(env: TrainEnv, key: jax.Array, num_envs: int, task_params: Any) -> tuple[Any, Any]:
    """`num_envs` fresh episodes: obs and state with leading axis B."""
    return jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, num_envs), task_params)


def collect(
    key: jax.Array,
    params: Any,
    apply_fn: ApplyFn,
    env: TrainEnv,
    env_state: Any,
    obs: Any,
    task_params: Any,
    num_steps: int,
    gamma: float,
    timeouts_terminal: bool,
    constrain: Callable[[Any], Any] = lambda x: x,
    per_device: Callable[[Callable], Callable] = lambda f: f,
) -> tuple[Any, Any, Transition]:
    """Run `num_steps` steps of the current policy in B envs.

    Returns `(env_state, obs, transitions)` with transitions `[T, B, ...]`. When time-outs are not
    terminal, the reward of a truncated step gets `gamma * V(final_obs)` added (bootstrap).
    `constrain` re-applies the env-axis sharding to the carry; `per_device` maps the batched env
    step `(keys, state, action, task_params)` to one that steps each device's envs where they are.
    """
    step_batch = per_device(jax.vmap(env.step, in_axes=(0, 0, 0, None)))

    def one_step(carry, key_step):
        env_state, obs = carry
        key_action, key_env = jax.random.split(key_step)
        out = apply_fn(params, obs)
        action = out.pi.sample(key_action)
        keys_env = jax.random.split(key_env, action.shape[0])
        next_obs, env_state, result = step_batch(keys_env, env_state, action, task_params)
        reward, done = result.reward, result.terminated | result.cut
        if timeouts_terminal:
            done = done | result.truncated
        else:
            final_value = apply_fn(params, result.final_obs).value
            bootstrap = result.truncated & ~(result.terminated | result.cut)
            reward = reward + jnp.where(bootstrap, gamma * final_value, 0.0)
            done = done | result.truncated
        transition = Transition(
            obs, action, out.pi.log_prob(action), out.value, out.cost_value,
            reward.astype(jnp.float32), result.cost.astype(jnp.float32), done, result.stats,
        )
        return constrain((env_state, next_obs)), transition

    keys = jax.random.split(key, num_steps)
    (env_state, obs), transitions = jax.lax.scan(one_step, (env_state, obs), keys)
    return env_state, obs, transitions
