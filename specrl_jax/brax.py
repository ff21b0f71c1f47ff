"""Brax adapter: a continuous-action world joined with a spec source through the task loop, as a
`brax.envs.Env` that `brax.training`'s PPO and SAC train as they are.

    from brax.training.agents.ppo import train as ppo
    from specrl_jax.brax import BraxTaskEnv, wrap_for_training

    env = BraxTaskEnv(task_env)                    # task_env: specrl_jax.tasks.TaskEnv
    ppo.train(env, num_timesteps=..., episode_length=1000, wrap_env_fn=wrap_for_training, ...)

- `reset(key) -> State`, `step(state, action) -> State`, without a key in the step: the adapter's
  own key travels in `State.pipeline_state` (`AdapterState`) with the task loop's state.
- Actions are Brax's `[-1, 1]^action_size`, scaled to the world's box.
- Observation: the task's observation (e.g. GenZ-LTL's reduced one) flattened to one float32
  vector (`flatten=True`) or kept as a dict (Brax's dict observations).
- Reward: the task loop's reward (`tasks.reward_progress`: +1 on progress, -1 on violation, else
  the world's own, -1 for crossing a Zone wall), or
  `reward_fn(info)` over the loop's step info.
- Episode ends: the task loop's own auto-reset (`envs.wrappers.reset_done`): every ended episode
  restarts on a fresh layout with a fresh task. `done` = terminated or truncated;
  `info["truncation"]` marks the horizon (`params.max_steps`, set from Brax's `episode_length`).
- `State.metrics`: per-step `reaches`, `violations`, `successes`, `world_terminations`,
  `timeouts` (float32), summed per episode by the wrappers and by Brax's evaluator.

Brax's own `envs.training.wrap` ends in an `AutoResetWrapper` that restores a cached first state
(same layout and task for an env slot forever); the adapter refuses it at trace time. Use
`wrap_for_training` (the `wrap_env_fn` of `ppo.train` / `sac.train`): `VmapWrapper` and an
episode-metrics wrapper, the reset left to the task loop.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

try:
    from brax.envs.base import Env as _BraxEnv
    from brax.envs.base import State, Wrapper
    from brax.envs.wrappers.training import VmapWrapper
except ImportError as err:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "specrl_jax.brax needs Brax (brax.training): pip install 'specrl_jax[brax]' "
        "(Python >= 3.11); no PyTorch is needed"
    ) from err

from specrl_jax.tasks import TaskEnv, TaskState


def _device_put_replicated(x: Any, devices: list) -> Any:
    """`x` stacked once per device along a new leading axis, that axis sharded over `devices`
    (what Brax's pmap trainers expect from `jax.device_put_replicated`)."""
    mesh = jax.sharding.Mesh(np.asarray(devices), ("devices",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("devices"))
    stack = lambda leaf: jnp.broadcast_to(jnp.asarray(leaf)[None], (len(devices), *jnp.shape(leaf)))
    return jax.device_put(jax.tree.map(stack, x), sharding)


def _jax_compat_for_brax() -> None:
    """Brax 0.14.2's PPO and SAC call `jax.device_put_replicated`, which JAX 0.10 removed (its
    deprecation raises); where it is missing, provide it by its documented replacement
    (`jax.device_put` with a sharding). Nothing else of JAX is touched."""
    try:
        jax.device_put_replicated  # noqa: B018
    except AttributeError:
        jax.device_put_replicated = _device_put_replicated


_jax_compat_for_brax()

#: per-step metrics the adapter reports, from the task loop's step info
METRICS = ("reaches", "violations", "successes", "world_terminations", "timeouts")


@struct.dataclass
class AdapterState:
    """What `State.pipeline_state` carries: the task loop's state and the adapter's key."""

    task: TaskState
    key: jax.Array  # the key of the next step (Brax steps take none)


def _flatten(obs: Any) -> jax.Array:
    """float32[D]: every leaf of `obs`, in `jax.tree.leaves` order (dict keys sorted)."""
    return jnp.concatenate([jnp.ravel(x).astype(jnp.float32) for x in jax.tree.leaves(obs)])


class BraxTaskEnv(_BraxEnv):
    """A `TaskEnv` over a continuous-action world as a (single, unbatched) Brax env.

    Args:
        task: the task loop (world x spec source x observation).
        params: the world's params (default: its defaults); `max_steps` is the horizon.
        source_params: the source's params (default: `source.init_params()`), fixed: a Brax
            trainer carries no task distribution, so curricula do not advance.
        reward_fn: `info -> float32[]` over the loop's step info (default: the loop's reward).
        flatten: one float32 observation vector (else the task's observation dict).
    """

    def __init__(self, task: TaskEnv, params: Any = None, source_params: Any = None,
                 reward_fn: Callable[[dict[str, Any]], jax.Array] | None = None,
                 flatten: bool = True):
        if not isinstance(task, TaskEnv):
            raise TypeError(f"task must be a specrl_jax.tasks.TaskEnv, got {type(task).__name__}")
        space = task.env.action_space
        if hasattr(space, "n") or not hasattr(space, "low"):
            raise ValueError(
                f"Brax trains continuous actions; {task.env!r} has action space {space!r} "
                "(use a Zone or Arm world)"
            )
        if len(space.shape) != 1:
            raise ValueError(f"expected a 1-D action box, got shape {space.shape}")
        self.task = task
        self.params = task.env.default_params if params is None else params
        self.source_params = (task.source.init_params() if source_params is None
                              else source_params)
        self.reward_fn = reward_fn
        self.flatten = flatten
        self._low = np.asarray(space.low, np.float32) * np.ones(space.shape, np.float32)
        self._high = np.asarray(space.high, np.float32) * np.ones(space.shape, np.float32)

    def with_horizon(self, max_steps: int) -> BraxTaskEnv:
        """The same env with the task horizon `max_steps` (Brax's `episode_length`)."""
        if int(max_steps) < 1:
            raise ValueError(f"episode_length must be >= 1, got {max_steps!r}")
        return BraxTaskEnv(self.task, self.params.replace(max_steps=int(max_steps)),
                           self.source_params, self.reward_fn, self.flatten)

    # ---------------------------------------------------------------------------------------
    # Brax's Env interface

    def reset(self, rng: jax.Array) -> State:
        """A fresh layout and task; `rng` a raw uint32[2] key (Brax's) or a typed key."""
        key_reset, key_next = jax.random.split(rng)
        obs, task_state = self.task.reset(key_reset, self.params, None, self.source_params)
        zero = jnp.zeros((), jnp.float32)
        return State(
            pipeline_state=AdapterState(task_state, key_next),
            obs=self._obs(obs),
            reward=zero,
            done=zero,
            metrics={name: zero for name in METRICS},
            info={"truncation": zero, "steps": zero},
        )

    def step(self, state: State, action: jax.Array) -> State:
        """One task step (world step, label, source step, reward) with the loop's auto-reset."""
        if "first_obs" in state.info:
            raise ValueError(
                "this env is wrapped in Brax's AutoResetWrapper, which restores a cached first "
                "state (same layout and task forever); pass wrap_env_fn="
                "specrl_jax.brax.wrap_for_training to brax's train"
            )
        key, key_step = jax.random.split(state.pipeline_state.key)
        obs, task_state, reward, terminated, truncated, info = self.task.step(
            key_step, state.pipeline_state.task, self._scale(action), self.params, False,
            self.source_params,
        )
        if self.reward_fn is not None:
            reward = self.reward_fn(info)
        f32 = lambda x: jnp.asarray(x).astype(jnp.float32)
        metrics = {
            "reaches": f32(info["progress"]),
            "violations": f32(info["violation"]),
            "successes": f32(info["success"]),
            "world_terminations": f32(info["env_terminated"]),
            "timeouts": f32(truncated),
        }
        return state.replace(
            pipeline_state=AdapterState(task_state, key),
            obs=self._obs(obs),
            reward=f32(reward),
            done=f32(terminated | truncated),
            metrics=metrics,
            info={**state.info, "truncation": f32(truncated), "steps": f32(info["steps"])},
        )

    @property
    def observation_size(self) -> int | dict[str, tuple[int, ...]]:
        obs = jax.eval_shape(self.reset, jax.random.PRNGKey(0)).obs
        if self.flatten:
            return int(obs.shape[0])
        return {name: tuple(leaf.shape) for name, leaf in obs.items()}

    @property
    def action_size(self) -> int:
        return int(self._low.shape[0])

    @property
    def backend(self) -> str:
        return "mjx" if hasattr(self.task.env, "mjx_model") else "jax"

    # ---------------------------------------------------------------------------------------

    def _scale(self, action: jax.Array) -> jax.Array:
        """Brax's [-1, 1] -> the world's [low, high] (clipped first)."""
        unit = (jnp.clip(action, -1.0, 1.0) + 1.0) * 0.5
        return self._low + unit * (self._high - self._low)

    def _obs(self, obs: Any) -> Any:
        return _flatten(obs) if self.flatten else jax.tree.map(
            lambda x: jnp.asarray(x, jnp.float32), dict(obs))


class EpisodeMetricsWrapper(Wrapper):
    """Keeps what Brax's trainers read beside the adapter's own `truncation` and `steps`: the
    running `episode_metrics` (`sum_reward`, `length` and each metric) and `episode_done`, over a
    batched env whose episodes reset themselves (no cached state, no reset here)."""

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        zeros = jnp.zeros_like(state.reward)
        state.info["episode_metrics"] = {"sum_reward": zeros, "length": zeros,
                                         **{name: zeros for name in state.metrics}}
        state.info["episode_done"] = zeros
        return state

    def step(self, state: State, action: jax.Array) -> State:
        keep = 1.0 - state.info["episode_done"]
        running = state.info["episode_metrics"]
        state = self.env.step(state, action)
        new = {"sum_reward": state.reward, "length": jnp.ones_like(state.reward),
               **{name: value for name, value in state.metrics.items() if name != "reward"}}
        state.info["episode_metrics"] = {name: running[name] * keep + value
                                         for name, value in new.items()}
        state.info["episode_done"] = state.done
        return state


def wrap_for_training(env: BraxTaskEnv, episode_length: int = 1000, action_repeat: int = 1,
                      randomization_fn: Any = None) -> Wrapper:
    """Brax's `wrap_env_fn` for a `BraxTaskEnv`: the horizon set to `episode_length`, a vmapped
    batch, episode metrics; ended episodes restart through the task loop's fresh reset."""
    if not isinstance(env, BraxTaskEnv):
        raise TypeError(f"expected a specrl_jax.brax.BraxTaskEnv, got {type(env).__name__}")
    if int(action_repeat) != 1:
        raise ValueError(
            f"action_repeat must be 1 (the automaton reads the label of every step), got "
            f"{action_repeat!r}"
        )
    if randomization_fn is not None:
        raise ValueError("randomization_fn is not supported: layouts are sampled at every reset")
    return EpisodeMetricsWrapper(VmapWrapper(env.with_horizon(episode_length)))
