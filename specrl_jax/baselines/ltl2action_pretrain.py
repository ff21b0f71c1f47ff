"""LTL2Action's optional encoder pretraining ("LTLBootcamp"), through the shared PPO.

The original (`Simple-LTL-Env-v0`, `--dumb-ac`): no observation; the action names the letter that
holds this step (one of the alphabet's letters, never none); the task is the training sampler's
formula, progressed by that letter: +1 and the end of the episode when it progresses to true, -1
and the end when to false; horizon 75. The network is the R-GCN with a linear actor over the
letters and a linear critic; PPO as the original: 16 envs x 512 steps, minibatch 1,024, 2 epochs,
lr 1e-3, gamma 0.9, GAE lambda 0.5, clip 0.1, entropy 0.01. The R-GCN's parameters then start
the downstream network (`ltl2action.make_method(encoder=...)`, or `pretrain_steps=...` to run
this first).

Here the symbol world is `rad_pretrain.SymbolWorld` over the world's non-empty assignments, run by
the one task loop over the same progression source (formulas and curriculum stages) the
downstream method trains on.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from specrl_jax.baselines import ltl2action
from specrl_jax.baselines.ppo import make_train
from specrl_jax.baselines.ppo.networks import Categorical, PolicyOutput, unit_columns
from specrl_jax.baselines.ppo.train import PPOConfig
from specrl_jax.baselines.rad_pretrain import SymbolWorld, pretrain_config, save_encoder
from specrl_jax.tasks.progression import num_features

#: the symbol task's horizon (the original's Simple-LTL-Env)
HORIZON = 75

__all__ = ["HORIZON", "BootcampNetwork", "bootcamp_config", "encoder_params", "load_encoder",
           "make_bootcamp", "pretrain_encoder", "save_encoder"]


class BootcampNetwork(nn.Module):
    """The R-GCN (submodule `ltl2action.ENCODER`) with a linear actor over the letters and a
    linear critic on its 32-d embedding, as the original's `--dumb-ac`."""

    propositions: tuple[str, ...]
    num_actions: int

    @nn.compact
    def __call__(self, obs: ltl2action.FormulaObs) -> PolicyOutput:
        emb = ltl2action.RGCNEncoder(num_features(len(self.propositions)), name=ltl2action.ENCODER)(
            obs.tokens, obs.parent, obs.edge)
        logits = nn.Dense(self.num_actions, kernel_init=unit_columns, name="actor")(emb)
        value = nn.Dense(1, kernel_init=unit_columns, name="critic")(emb)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(Categorical(logits), value, zeros, zeros)


def make_bootcamp(alphabet: np.ndarray, propositions: tuple[str, ...], formulas: Sequence[str],
                  stages: Sequence[int] | None = None, family: str = "letter"
                  ) -> ltl2action.LTL2Action:
    """The symbol task over `alphabet`'s non-empty rows (bool[A, P]) on `formulas` (by
    curriculum stages of sizes `stages`, as `ltl2action.make_method` draws them)."""
    alphabet = np.asarray(alphabet, bool)
    letters = alphabet[alphabet.any(axis=1)]
    if letters.shape[0] == 0:
        raise ValueError("the alphabet has no non-empty assignment to act with")
    world = SymbolWorld(letters, tuple(propositions), HORIZON)
    network = BootcampNetwork(tuple(propositions), int(letters.shape[0]))
    return ltl2action.make_method(world, world.default_params, family, formulas=formulas,
                                  stages=stages, network=network)


def bootcamp_config(**overrides: Any) -> PPOConfig:
    """The original's pretraining PPO (the same settings as RAD-Embeddings' pretraining)."""
    return pretrain_config(**overrides)


def encoder_params(params: Any) -> Any:
    """The R-GCN's part of a network's parameters, as `ltl2action.with_encoder` takes it."""
    return {"params": params["params"][ltl2action.ENCODER]}


def pretrain_encoder(alphabet: np.ndarray, propositions: tuple[str, ...], formulas: Sequence[str],
                     stages: Sequence[int] | None, family: str, key: jax.Array, steps: int,
                     log: Callable[[str], None] = print, chunk_updates: int = 50,
                     **ppo_overrides: Any) -> Any:
    """Pretrain the R-GCN on the symbol task for about `steps` env steps (whole updates of
    `bootcamp_config(**ppo_overrides)`, at least one); returns `encoder_params` of the result."""
    method = make_bootcamp(alphabet, propositions, formulas, stages, family)
    config = bootcamp_config(total_timesteps=max(int(steps), 1), **ppo_overrides)
    trainer = make_train(config, method)
    runner = jax.jit(trainer.init)(key)
    updates = jax.jit(trainer.updates, static_argnums=1)
    done = 0
    while done < config.num_updates:
        n = min(chunk_updates, config.num_updates - done)
        runner, metrics = updates(runner, chunk_updates, jnp.int32(n))
        done += n
        m = {k: float(np.sum(np.asarray(v)[:n])) for k, v in metrics.items()}
        episodes = max(m["episodes"], 1.0)
        log(f"LTL bootcamp: update {done}/{config.num_updates}  env steps "
            f"{done * config.batch_size:,}  success_rate {m['successes'] / episodes:.3f}  "
            f"violation_rate {m['violations'] / episodes:.3f}")
    return encoder_params(runner.params)


def load_encoder(path: str | Path, num_propositions: int) -> Any:
    """R-GCN parameters saved by `save_encoder(path, encoder_params(...), meta)`, for
    `num_propositions` propositions.

    Raises:
        ValueError: no such file, no R-GCN parameters in it, or made for another number of
            propositions.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no pretrained LTL2Action encoder at {path}; make one with "
                         "`python benchmarks/ltl2action_pretrain.py` (see its docstring)")
    stored = serialization.msgpack_restore(path.read_bytes())
    try:
        width = np.shape(stored["params"]["Dense_0"]["kernel"])[0]
    except (KeyError, TypeError):
        raise ValueError(f"{path} holds no LTL2Action encoder parameters") from None
    if width != num_features(num_propositions):
        raise ValueError(f"the encoder at {path} reads {width} formula tokens; "
                         f"{num_propositions} propositions need {num_features(num_propositions)}")
    return jax.tree.map(jnp.asarray, stored)
