"""The trainer's view of the task loop: a method's training env is `tasks.TaskEnv` with the
method's observation and action split, and its training signals computed from the loop's events.
No method keeps a copy of the loop.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from specrl_jax.baselines.ppo.rollout import StepResult
from specrl_jax.tasks import TaskEnv

#: (info of a task step) -> (reward, cost, cut) float32[], float32[], bool[]
Signals = Callable[[dict[str, Any]], tuple[jax.Array, jax.Array, jax.Array]]
#: (network action) -> (world action, take_epsilon bool[])
SplitAction = Callable[[jax.Array], tuple[jax.Array, jax.Array]]


def no_epsilon(action: jax.Array) -> tuple[jax.Array, jax.Array]:
    return action, jnp.zeros((), bool)


def pass_world_reward(info: dict[str, Any]) -> jax.Array:
    """float32[]: +1 on success, -1 on violation, else the world's own reward (-1 for crossing a
    Zone wall): LTL2Action's and DeepLTL's originals keep the env's reward on the steps that
    neither complete nor violate their task, RAD-Embeddings' adds it to its DFA reward (the same
    on a Zone world: no zone reaches a wall)."""
    ended = info["success"] | info["violation"]
    outcome = info["success"].astype(jnp.float32) - info["violation"].astype(jnp.float32)
    return jnp.where(ended, outcome, info["env_reward"])


@dataclasses.dataclass(frozen=True)
class TaskTrainEnv:
    """`rollout.TrainEnv` over a `TaskEnv` (auto-resetting; `task_params` = source params)."""

    task: TaskEnv
    params: Any
    signals: Signals
    split_action: SplitAction = no_epsilon

    def reset(self, key: jax.Array, task_params: Any) -> tuple[Any, Any]:
        return self.task.reset(key, self.params, None, task_params)

    def step(self, key: jax.Array, state: Any, action: jax.Array, task_params: Any):
        world_action, take_epsilon = self.split_action(action)
        obs, state, _, terminated, truncated, info = self.task.step(
            key, state, world_action, self.params, take_epsilon, task_params
        )
        reward, cost, cut = self.signals(info)
        f32 = lambda x: jnp.asarray(x).astype(jnp.float32)
        done = terminated | truncated
        stats = {
            "episodes": f32(done),
            "successes": f32(info["success"]),
            "violations": f32(info["violation"]),
            "reaches": f32(info["progress"]),
            "timeouts": f32(truncated),
            "_task_id": getattr(info["task"], "task_id", jnp.int32(-1)),
            "_finished": done,
            "_success": info["success"],
        }
        result = StepResult(reward=f32(reward), cost=f32(cost), terminated=terminated,
                            truncated=truncated, cut=cut, final_obs=info["final_observation"],
                            stats=stats)
        return obs, state, result
