"""The task loop: a world x a spec source, the one path that training and evaluation both run.

Per step (reference notes, automata section 3): world step (or an epsilon step) -> label ->
source step -> success / violation / accepting visit -> reward -> termination -> auto-reset.

- The reset label is never fed to the source; an episode starts in its task's initial state.
- An epsilon step (`take_epsilon` asks for a slot and the task has an epsilon edge there) does not
  step the world (observation and label are kept) and counts toward the horizon. Asking for one
  where none exists steps the world with `action` instead.
- A task ends on success (finite-horizon tasks), on violation and on the world's own
  termination; it is truncated at `params.max_steps` task steps.
- Reward: `reward_progress` by default (+1 on progress, -1 on violation, else the world's own
  reward, e.g. -1 for crossing a Zone wall; 0 on epsilon steps); a method derives its own
  training signals from `info`'s events (and `info["env_reward"]`) instead.
- Auto-reset (`envs.wrappers.reset_done`, the project's one auto-reset): a fresh layout and a
  fresh task (an automaton source moves to the next spec of its bank).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from specrl_jax import automata
from specrl_jax.envs.base import Obs
from specrl_jax.envs.wrappers import reset_done, select_tree
from specrl_jax.tasks.sources import AutomatonSource, Events


@struct.dataclass
class TaskState:
    """The state of one task episode."""

    env_state: Any  # the world's state
    obs: Obs  # last world observation, returned by an epsilon step (`()` where none can happen)
    propositions: jax.Array  # bool[P], last label (all False at reset)
    task: Any  # the source's task (AutomatonTask, SequenceTask)
    time: jax.Array  # int32[], task steps so far (world steps + epsilon steps)
    steps_in_q: jax.Array  # int32[], steps since the task last made progress or changed state
    num_accepting: jax.Array  # int32[], accepting transitions taken this episode
    success: jax.Array  # bool[], the episode has succeeded (finite-horizon tasks)
    violation: jax.Array  # bool[], the episode has violated its task

    @property
    def q(self) -> jax.Array:
        """int32[]: the automaton state (automaton tasks)."""
        return self.task.q

    @property
    def spec(self) -> Any:
        """The episode's `CompiledSpec` (automaton tasks)."""
        return self.task.spec

    @property
    def spec_index(self) -> jax.Array:
        """int32[]: the episode's spec in its source's bank (automaton tasks)."""
        return self.task.spec_index


def reward_progress(events: Events, is_epsilon: jax.Array,
                    env_reward: jax.Array | float = 0.0) -> jax.Array:
    """float32[]: +1 on progress, -1 on violation, else the world's `env_reward`; 0 on epsilon
    steps."""
    reward = jnp.where(events.violation, -1.0, jnp.where(events.progress, 1.0, env_reward))
    return jnp.where(is_epsilon, 0.0, reward).astype(jnp.float32)


Observe = Callable[[Obs, TaskState], Any]


class TaskEnv:
    """`env` x a spec source, auto-resetting.

    Observation: `observe(world_obs, task_state)` (default: the world's observation dict).
    Action: the world's action, plus an optional `take_epsilon` (bool, or an int32 slot).
    State: `TaskState`. `info` holds `propositions`, the step's events `progress`, `success`,
    `violation`, `accepted`, plus `epsilon` (an epsilon step was taken), `env_terminated`,
    `num_accepting_visits`, `steps`, `task` (the task as it was before the step) and, from
    the auto-reset, `final_observation`; all describe the step taken, before any reset.

    `specs` may be a stacked batch of compiled specs (an `AutomatonSource` is built) or a source.
    """

    def __init__(self, env: Any, specs: Any, observe: Observe | None = None):
        self.env = env
        self.source = specs if hasattr(specs, "takes_epsilon") else AutomatonSource(specs, env.alphabet)
        self.observe = observe

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    @property
    def specs(self) -> Any:
        return self.source.specs

    @property
    def num_specs(self) -> int:
        return self.source.num_tasks

    def _observe(self, obs: Obs, state: TaskState) -> Any:
        return obs if self.observe is None else self.observe(obs, state)

    def reset(self, key: jax.Array, params: Any = None, spec_index: jax.Array | None = None,
              source_params: Any = None) -> tuple[Any, TaskState]:
        """Fresh layout and task (automaton source: the spec at `spec_index`, or a uniform one)."""
        params = self.env.default_params if params is None else params
        key_env, key_task = jax.random.split(key)
        obs, env_state = self.env.reset(key_env, params)
        zero = jnp.zeros((), jnp.int32)
        state = TaskState(
            env_state=env_state,
            obs=obs if self.source.may_take_epsilon else (),
            propositions=jnp.zeros((self.env.num_propositions,), bool),
            task=self.source.reset(key_task, source_params, spec_index),
            time=zero,
            steps_in_q=zero,
            num_accepting=zero,
            success=jnp.zeros((), bool),
            violation=jnp.zeros((), bool),
        )
        return self._observe(obs, state), state

    def step_task(self, key: jax.Array, state: TaskState, action: jax.Array, params: Any = None,
                  take_epsilon: jax.Array | bool = False, source_params: Any = None):
        """One task step without auto-reset: `(obs, state, reward, terminated, truncated, info)`."""
        params = self.env.default_params if params is None else params
        key_env, key_task = jax.random.split(key)
        slot = automata.epsilon_slot(take_epsilon)
        obs, env_state, env_reward, env_terminated, _, env_info = self.env.step(
            key_env, state.env_state, action, params
        )
        propositions = env_info["propositions"]
        if self.source.may_take_epsilon:  # static: an epsilon step keeps the world as it was
            is_epsilon = self.source.takes_epsilon(state.task, slot)
            obs = select_tree(is_epsilon, state.obs, obs)
            env_state = select_tree(is_epsilon, state.env_state, env_state)
            propositions = jnp.where(is_epsilon, state.propositions, propositions)
            env_terminated = ~is_epsilon & env_terminated
            env_reward = jnp.where(is_epsilon, 0.0, env_reward)
        else:
            is_epsilon = jnp.zeros((), bool)
        symbol = env_info.get("symbol") if self.source.symbol_is_row else None

        task, events = self.source.step(key_task, state.task, propositions, symbol, is_epsilon,
                                        slot, source_params)
        time = state.time + 1
        terminated = env_terminated | events.violation | events.success
        truncated = (time >= params.max_steps) & ~terminated
        new_state = state.replace(
            env_state=env_state,
            obs=obs if self.source.may_take_epsilon else (),
            propositions=propositions,
            task=task,
            time=time,
            steps_in_q=jnp.where(events.progress | events.violation, 0, state.steps_in_q + 1),
            num_accepting=state.num_accepting + events.accepted.astype(jnp.int32),
            success=state.success | events.success,
            violation=state.violation | events.violation,
        )
        info = {
            **{name: value for name, value in env_info.items() if name != "symbol"},
            "propositions": propositions,
            "progress": events.progress,
            "success": events.success,
            "violation": events.violation,
            "accepted": events.accepted,
            "epsilon": is_epsilon,
            "env_terminated": env_terminated,
            "env_reward": jnp.asarray(env_reward, jnp.float32),
            "num_accepting_visits": new_state.num_accepting,
            "steps": time,
            "task": state.task,
        }
        reward = reward_progress(events, is_epsilon, env_reward)
        return self._observe(obs, new_state), new_state, reward, terminated, truncated, info

    def step(self, key: jax.Array, state: TaskState, action: jax.Array, params: Any = None,
             take_epsilon: jax.Array | bool = False, source_params: Any = None):
        """One task step; an ended episode restarts on a fresh layout with a fresh task."""
        params = self.env.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, new_state, reward, terminated, truncated, info = self.step_task(
            key_step, state, action, params, take_epsilon, source_params
        )
        next_index = self.source.next_index(state.task)
        obs, new_state, info = reset_done(
            terminated | truncated,
            lambda k: self.reset(k, params, next_index, source_params),
            key_reset, obs, new_state, info,
        )
        return obs, new_state, reward, terminated, truncated, info
