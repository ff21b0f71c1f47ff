"""Gymnasium bridge: `import specrl_jax.gym` registers every specrl_jax env ID with Gymnasium.

`gymnasium.make("LetterLTL0-v0")` gives a `GymEnv`: numpy observations in the original
benchmark's layout (`env.original_observation_space`: a flat vector, or for camera worlds the
original's dict with its `vision` key), the world's reward (0, and -1 on the step that crosses
a Zone wall, as the original's), `info["propositions"]` a set of
proposition names. `gymnasium.make_vec(env_id, num_envs=N)` gives a `GymVectorEnv` that steps the
N worlds in one compiled call with same-step auto-reset. Both are thin host shells over the JAX
env: they jit once, hold the only stateful key, and seed it through `reset(seed=...)`. Their
compiled functions are shared by every bridge over the same world config, so a second
`gymnasium.make` of one ID compiles nothing.

Processes: JAX cannot run in a child forked after JAX started (its threads deadlock the child),
so importing this module makes "spawn" the default multiprocessing start method where the
platform's default is "fork" and no method was chosen yet: `gymnasium.make_vec(...,
vectorization_mode="async")` then works (workers import specrl_jax afresh; guard the script's
entry point with `if __name__ == "__main__":`). A bridge built in such a forked child raises
`RuntimeError` instead of hanging.
"""

from __future__ import annotations

import multiprocessing
import os
from typing import Any, ClassVar

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.vector import AutoresetMode

import specrl_jax
from specrl_jax.envs import compiled, spaces
from specrl_jax.envs.wrappers import batch

#: set in a child forked from a process whose JAX backends had started
_FORKED_AFTER_JAX = False


def _after_fork_in_child() -> None:
    global _FORKED_AFTER_JAX
    from jax._src import xla_bridge

    _FORKED_AFTER_JAX = _FORKED_AFTER_JAX or xla_bridge.backends_are_initialized()


def _use_spawn_by_default() -> None:
    """"spawn" as the default start method where it would be "fork" and none was chosen."""
    if (
        multiprocessing.get_start_method(allow_none=True) is None
        and multiprocessing.get_all_start_methods()[0] == "fork"
    ):
        multiprocessing.set_start_method("spawn")


def _check_not_forked() -> None:
    if _FORKED_AFTER_JAX:
        raise RuntimeError(
            "this process was forked from one in which JAX had started; JAX deadlocks after a "
            "fork. Use gymnasium.make_vec(env_id, num_envs) (one compiled call for all worlds), "
            "or vectorization_mode='async' with vector_kwargs={'context': 'spawn'}"
        )


def to_gymnasium_space(space: Any) -> gymnasium.spaces.Space:
    """A specrl_jax action space as the equivalent gymnasium space."""
    if isinstance(space, spaces.Discrete) and space.shape == ():
        return gymnasium.spaces.Discrete(space.n)
    if isinstance(space, spaces.Box):
        return gymnasium.spaces.Box(space.low, space.high, space.shape, np.dtype(space.dtype))
    raise TypeError(f"no gymnasium equivalent for the action space {space!r}")


def _make(env_id: str, overrides: dict[str, Any]) -> tuple[Any, Any]:
    env, params = specrl_jax.make(env_id, **overrides)
    if not hasattr(env, "original_observation_space") or not hasattr(env, "original_observation"):
        raise TypeError(
            f"{env_id!r} provides no original_observation_space / original_observation, "
            "which the Gymnasium bridge needs"
        )
    return env, params


def _numpy(obs: Any) -> Any:
    """An observation (an array or a dict of arrays) as numpy."""
    return jax.tree.map(np.asarray, obs)


def _seed_key(seed: int | None, rng: np.random.Generator) -> jax.Array:
    return jax.random.key(int(rng.integers(2**31)) if seed is None else seed)


class GymEnv(gymnasium.Env):
    """One specrl_jax world as a `gymnasium.Env` (numpy in, numpy out)."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, env_id: str, render_mode: str | None = None, **overrides: Any):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported; accepted: None")
        _check_not_forked()
        self.env, self.params = _make(env_id, overrides)
        self.observation_space = self.env.original_observation_space
        self.action_space = to_gymnasium_space(self.env.action_space)
        self.propositions = tuple(self.env.propositions)
        self._key: jax.Array | None = None
        self._state: Any = None
        env = self.env

        def reset(key: jax.Array, params: Any) -> tuple:
            obs, state = env.reset(key, params)
            label = env.label(state) if hasattr(env, "label") else None
            return env.original_observation(obs), state, label

        def step(key: jax.Array, state: Any, action: jax.Array, params: Any) -> tuple:
            obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
            return (
                env.original_observation(obs),
                state,
                reward,
                terminated,
                truncated,
                info["propositions"],
            )

        self._reset, self._step = compiled.shared(
            env, "gym single", lambda: (jax.jit(reset), jax.jit(step))
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None or self._key is None:
            self._key = _seed_key(seed, self.np_random)
        self._key, key = jax.random.split(self._key)
        obs, self._state, label = self._reset(key, self.params)
        props = set() if label is None else self._names(np.asarray(label))
        return _numpy(obs), {"propositions": props}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action)
        self.env.action_space.check(action)
        self._key, key = jax.random.split(self._key)
        out = self._step(
            key, self._state, jnp.asarray(action, self.env.action_space.dtype), self.params
        )
        obs, self._state, reward, terminated, truncated, label = out
        obs, reward, terminated, truncated, label = jax.device_get(
            (obs, reward, terminated, truncated, label)
        )
        info = {"propositions": self._names(label)}
        return _numpy(obs), float(reward), bool(terminated), bool(truncated), info

    def _names(self, label: np.ndarray) -> set[str]:
        return {name for name, on in zip(self.propositions, label) if on}


class GymVectorEnv(gymnasium.vector.VectorEnv):
    """`num_envs` worlds stepped by one compiled call, auto-reset in the same step.

    `info["propositions"]` is bool[N, P] (columns in `self.propositions` order); when an episode
    ends, `info["final_obs"]` holds its last observation where `info["_final_obs"]` is True.
    `reset(options={"keys": keys})` starts world i from `keys[i]` (typed keys or their
    `jax.random.key_data`), to replay chosen episodes.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "autoreset_mode": AutoresetMode.SAME_STEP,
        "render_modes": [],
    }

    def __init__(self, env_id: str, num_envs: int = 1, **overrides: Any):
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        _check_not_forked()
        self.env, self.params = _make(env_id, overrides)
        self.num_envs = num_envs
        self.propositions = tuple(self.env.propositions)
        self.single_observation_space = self.env.original_observation_space
        self.single_action_space = to_gymnasium_space(self.env.action_space)
        self.observation_space = gymnasium.vector.utils.batch_space(
            self.single_observation_space, num_envs
        )
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, num_envs)
        batched = batch(self.env, num_envs)
        original = jax.vmap(self.env.original_observation)
        self._key: jax.Array | None = None
        self._state: Any = None

        def reset(key: jax.Array, params: Any) -> tuple:
            obs, state = batched.reset(key, params)
            return original(obs), state

        def step(key: jax.Array, state: Any, action: jax.Array, params: Any) -> tuple:
            obs, state, reward, terminated, truncated, info = batched.step(
                key, state, action, params
            )
            final = original(info["final_observation"])
            return original(obs), state, reward, terminated, truncated, info["propositions"], final

        self._reset, self._step = compiled.shared(
            self.env, ("gym vector", num_envs), lambda: (jax.jit(reset), jax.jit(step))
        )

        def reset_each(keys: jax.Array, params: Any) -> tuple:
            obs, state = jax.vmap(self.env.reset, in_axes=(0, None))(keys, params)
            return original(obs), state

        self._reset_each = jax.jit(reset_each)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None or self._key is None:
            self._np_random, _ = gymnasium.utils.seeding.np_random(seed)
            self._key = _seed_key(seed, self._np_random)
        self._key, key = jax.random.split(self._key)
        if options and "keys" in options:  # replay chosen episodes: world i from keys[i]
            keys = options["keys"]
            if not jax.dtypes.issubdtype(keys.dtype, jax.dtypes.prng_key):
                keys = jax.random.wrap_key_data(jnp.asarray(keys, jnp.uint32))
            if keys.shape != (self.num_envs,):
                raise ValueError(f"options['keys'] holds {keys.shape} keys; expected "
                                 f"({self.num_envs},), one per world")
            obs, self._state = self._reset_each(keys, self.params)
        else:
            obs, self._state = self._reset(key, self.params)
        return _numpy(obs), {}

    def step(self, actions: Any) -> tuple:
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions)
        if actions not in self.action_space:
            raise ValueError(
                f"actions {actions.tolist()} (dtype {actions.dtype}) are not in {self.action_space}"
            )
        self._key, key = jax.random.split(self._key)
        actions = jnp.asarray(actions, self.env.action_space.dtype)
        obs, self._state, *rest = self._step(key, self._state, actions, self.params)
        obs, reward, terminated, truncated, label, final = jax.device_get((obs, *rest))
        done = terminated | truncated
        info = {"propositions": label, "_propositions": np.ones(self.num_envs, bool)}
        if done.any():
            info |= {"final_obs": final, "_final_obs": done}
        return _numpy(obs), reward.astype(np.float64), terminated, truncated, info


class GymMultiEnv(gymnasium.Env):
    """A multi-agent world (`env.agents`) as a `gymnasium.Env`, in the original's dict layout.

    Observation `{"agent_i": {"accelerometer_i": ..., "gremlins_lidar_i": ..., "wall_sensor_i":
    ...}}` (`env.original_observation_space`), action `{"agent_i": float32[A]}`. Reward 0.0 (the
    agents' sum); `terminated` once every agent has terminated, `truncated` at the horizon;
    `info["propositions"]` the set of joint propositions that hold, `info["terminated"]` and
    `info["truncated"]` per agent.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, env_id: str, render_mode: str | None = None, **overrides: Any):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported; accepted: None")
        self.env, self.params = specrl_jax.make(env_id, **overrides)
        if not hasattr(self.env, "agents"):
            raise TypeError(f"{env_id!r} is not a multi-agent world (it has no `agents`)")
        self.agents = tuple(self.env.agents)
        self.propositions = tuple(self.env.propositions)
        self.observation_space = self.env.original_observation_space
        stacked = self.env.action_space
        single = spaces.Box(stacked.low, stacked.high, stacked.shape[1:], stacked.dtype)
        self._single_action = single
        self.action_space = gymnasium.spaces.Dict(
            {agent: to_gymnasium_space(single) for agent in self.agents}, sort_keys=False
        )
        self._key: jax.Array | None = None
        self._state: Any = None
        self._reset, self._step, self._label = (
            jax.jit(self.env.reset), jax.jit(self.env.step), jax.jit(self.env.label)
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None or self._key is None:
            self._key = _seed_key(seed, self.np_random)
        self._key, key = jax.random.split(self._key)
        obs, self._state = self._reset(key, self.params)
        label = np.asarray(self._label(self._state))
        return self.env.original_observation(jax.device_get(obs)), {"propositions": self._names(label)}

    def step(self, action: Any) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        if not isinstance(action, dict) or set(action) != set(self.agents):
            got = sorted(action) if isinstance(action, dict) else type(action).__name__
            raise ValueError(f"action must be a dict with keys {list(self.agents)}; got {got}")
        for agent in self.agents:
            self._single_action.check(np.asarray(action[agent]), what=f"action[{agent!r}]")
        stacked = np.stack([np.asarray(action[agent]) for agent in self.agents])
        self._key, key = jax.random.split(self._key)
        out = self._step(key, self._state, jnp.asarray(stacked, self._single_action.dtype), self.params)
        obs, self._state, reward, terminated, truncated, info = out
        obs, reward, terminated, truncated, label = jax.device_get(
            (obs, reward, terminated, truncated, info["propositions"])
        )
        info = {
            "propositions": self._names(label),
            "terminated": dict(zip(self.agents, terminated.tolist())),
            "truncated": dict(zip(self.agents, truncated.tolist())),
        }
        all_terminated = bool(terminated.all())
        episode_over = bool((terminated | truncated).all())
        obs = self.env.original_observation(obs)
        return obs, float(reward.sum()), all_terminated, episode_over and not all_terminated, info

    def _names(self, label: np.ndarray) -> set[str]:
        return {name for name, on in zip(self.propositions, label) if on}


def register_all() -> list[str]:
    """Register every specrl_jax env ID not yet known to Gymnasium; returns the new IDs."""
    added = []
    from specrl_jax.envs import multi as multi_zone  # its IDs only: no world module loads

    multi_agent_ids = set(multi_zone.env_ids())
    for env_id in specrl_jax.list_envs():
        if env_id in gymnasium.registry:
            continue
        if env_id in multi_agent_ids:
            gymnasium.register(id=env_id, entry_point=GymMultiEnv, kwargs={"env_id": env_id})
        else:
            gymnasium.register(
                id=env_id,
                entry_point=GymEnv,
                vector_entry_point=GymVectorEnv,
                kwargs={"env_id": env_id},
            )
        added.append(env_id)
    return added


register_all()
_use_spawn_by_default()
os.register_at_fork(after_in_child=_after_fork_in_child)
