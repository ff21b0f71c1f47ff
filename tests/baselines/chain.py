"""A tiny chain world and method for trainer tests: walk right from cell 0 to cell N-1."""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp

from specrl_jax.baselines.ppo.networks import MLP, DiscreteHead, PolicyOutput, critic
from specrl_jax.baselines.ppo.rollout import StepResult
from specrl_jax.baselines.ppo.train import Method

LENGTH, HORIZON = 5, 12


@dataclasses.dataclass(frozen=True)
class ChainEnv:
    """Positions 0..LENGTH-1; action 1 moves right, 0 left; +1 and termination at the end."""

    def _obs(self, pos):
        return jax.nn.one_hot(pos, LENGTH)

    def reset(self, key, task_params):
        state = (jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))
        return self._obs(state[0]), state

    def step(self, key, state, action, task_params):
        pos, time = state
        pos = jnp.clip(pos + 2 * action - 1, 0, LENGTH - 1)
        time = time + 1
        terminated = pos == LENGTH - 1
        truncated = (time >= HORIZON) & ~terminated
        final_obs = self._obs(pos)
        done = terminated | truncated
        next_state = (jnp.where(done, 0, pos), jnp.where(done, 0, time))
        stats = {"episodes": done.astype(jnp.float32), "successes": terminated.astype(jnp.float32)}
        result = StepResult(
            terminated.astype(jnp.float32), jnp.where(terminated, 1.0, -1.0), terminated, truncated,
            jnp.zeros((), bool), final_obs, stats,
        )
        return self._obs(next_state[0]), next_state, result


class ChainNet(nn.Module):
    @nn.compact
    def __call__(self, obs):
        hidden = MLP((16,), "tanh")(obs)
        return PolicyOutput(
            DiscreteHead(2)(hidden),
            critic((16,), "tanh")(obs)[..., 0],
            critic((16,), "tanh")(obs)[..., 0],
            nn.softplus(critic((16,), "tanh")(obs)[..., 0]),
        )


@dataclasses.dataclass(frozen=True)
class ChainMethod(Method):
    env: ChainEnv = dataclasses.field(default_factory=ChainEnv)
    network: ChainNet = dataclasses.field(default_factory=ChainNet)

    def init_task_params(self):
        return jnp.zeros((), jnp.float32)

    def update_task_params(self, task_params, stats):
        return task_params + jnp.sum(stats["successes"])
