"""What the two formula-encoder pretrainings share (RAD-Embeddings' and LTL2Action's
LTLBootcamp): the symbol world, whose action names the symbol that occurs, and the original's
pretraining PPO settings."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.baselines.ppo.train import PPOConfig, make_train
from specrl_jax.baselines.runs import train_chunks
from specrl_jax.envs.spaces import Discrete


@struct.dataclass
class SymbolParams:
    max_steps: int = 75


@struct.dataclass
class SymbolState:
    time: jax.Array  # int32[]


class SymbolWorld:
    """A world without observation whose action is the alphabet row that holds this step.

    Observation: `{}`. Action: int32[] in 0..A-1. Labels: `alphabet[action]`, reported with
    `info["symbol"]`. Never terminates; truncated at `params.max_steps` by the task loop.
    """

    obs_kinds: dict[str, str] = {}

    def __init__(self, alphabet: np.ndarray, propositions: tuple[str, ...], max_steps: int = 75):
        self._alphabet = jnp.asarray(np.asarray(alphabet, bool))
        self.propositions = tuple(propositions)
        self._max_steps = int(max_steps)

    @property
    def alphabet(self) -> jax.Array:
        return self._alphabet

    @property
    def num_propositions(self) -> int:
        return len(self.propositions)

    @property
    def default_params(self) -> SymbolParams:
        return SymbolParams(self._max_steps)

    @property
    def action_space(self) -> Discrete:
        return Discrete(int(self._alphabet.shape[0]))

    def reset(self, key: jax.Array, params: Any = None) -> tuple[dict, SymbolState]:
        return {}, SymbolState(jnp.zeros((), jnp.int32))

    def step(self, key: jax.Array, state: SymbolState, action: jax.Array, params: Any = None):
        symbol = jnp.clip(jnp.asarray(action, jnp.int32), 0, self._alphabet.shape[0] - 1)
        info = {"propositions": self._alphabet[symbol], "symbol": symbol}
        no = jnp.zeros((), bool)
        return {}, SymbolState(state.time + 1), jnp.zeros(()), no, no, info



def pretrain_config(**overrides: Any) -> PPOConfig:
    """The original's pretraining PPO (`--dumb-ac`): 16 x 512 steps, minibatch 1,024, 2 epochs,
    lr 1e-3, gamma 0.9, GAE 0.5, clip 0.1, entropy 0.01, value 0.5, 10M steps."""
    settings = {"num_envs": 16, "num_steps": 512, "num_minibatches": 8, "update_epochs": 2,
                "lr": 1e-3, "gamma": 0.9, "gae_lambda": 0.5, "clip_eps": 0.1, "ent_coef": 0.01,
                "vf_coef": 0.5, "total_timesteps": 10_000_000}
    return PPOConfig(**{**settings, **overrides})


def run_pretraining(method: Any, config: PPOConfig, key: jax.Array, label: str,
                    log: Callable[[str], None] = print, chunk_updates: int = 50) -> Any:
    """Train one seed of `method` for `config.num_updates` updates through the run driver
    (`runs.train_chunks`), logging success and violation rates per chunk; returns the final
    network parameters."""
    trainer = make_train(config, method)
    runner = jax.tree.map(lambda x: x[None], jax.jit(trainer.init)(key))
    for runner, metrics, n, done in train_chunks(trainer, runner, 1, chunk_updates,
                                                 config.num_updates):
        m = {k: float(np.sum(np.asarray(v)[0, :n])) for k, v in metrics.items()}
        episodes = max(m["episodes"], 1.0)
        log(f"{label}: update {done}/{config.num_updates}  env steps "
            f"{done * config.batch_size:,}  success_rate {m['successes'] / episodes:.3f}  "
            f"violation_rate {m['violations'] / episodes:.3f}")
    return jax.tree.map(lambda x: x[0], runner.params)
