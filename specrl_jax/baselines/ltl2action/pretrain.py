"""LTL2Action's optional encoder pretraining ("LTLBootcamp"), through the shared PPO.

The original (`Simple-LTL-Env-v0`, `--dumb-ac`): no observation; the action names the letter that
holds this step (one of the alphabet's letters, never none); the task is the training sampler's
formula, progressed by that letter: +1 and the end of the episode when it progresses to true, -1
and the end when to false; horizon 75. The network is the R-GCN with a linear actor over the
letters and a linear critic; PPO as the original: 16 envs x 512 steps, minibatch 1,024, 2 epochs,
lr 1e-3, gamma 0.9, GAE lambda 0.5, clip 0.1, entropy 0.01. The R-GCN's parameters then start
the downstream network (`ltl2action.make_method(encoder=...)`, or `pretrain_steps=...` to run
this first).

Here the symbol world is `pretraining.SymbolWorld` over the world's non-empty assignments, run by
the one task loop over the same progression source (formulas and curriculum stages) the
downstream method trains on (`ltl2action.make_bootcamp`, `ltl2action.pretrain_encoder`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from specrl_jax.baselines.ltl2action.networks import (
    ENCODER,
    FormulaObs,
    RGCNEncoder,
    embed_formulas,
)
from specrl_jax.baselines.params_io import DATA_DIR, load_encoder_file, save_params
from specrl_jax.baselines.ppo.networks import Categorical, PolicyOutput, unit_columns
from specrl_jax.baselines.ppo.train import PPOConfig
from specrl_jax.baselines.pretraining import pretrain_config
from specrl_jax.tasks.progression import num_features

#: the symbol task's horizon (the original's Simple-LTL-Env)
HORIZON = 75



class BootcampNetwork(nn.Module):
    """The R-GCN (submodule `ENCODER`, `embed_formulas`) with a linear actor over the letters and
    a linear critic on its 32-d embedding, as the original's `--dumb-ac`."""

    propositions: tuple[str, ...]
    num_actions: int

    @nn.compact
    def __call__(self, obs: FormulaObs) -> PolicyOutput:
        emb = embed_formulas(RGCNEncoder(num_features(len(self.propositions)), name=ENCODER),
                             obs)
        logits = nn.Dense(self.num_actions, kernel_init=unit_columns, name="actor")(emb)
        value = nn.Dense(1, kernel_init=unit_columns, name="critic")(emb)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(Categorical(logits), value, zeros, zeros)


def bootcamp_config(**overrides: Any) -> PPOConfig:
    """The original's pretraining PPO (the same settings as RAD-Embeddings' pretraining)."""
    return pretrain_config(**overrides)


def encoder_params(params: Any) -> Any:
    """The R-GCN's part of a network's parameters, as `ltl2action.with_encoder` takes it."""
    return {"params": params["params"][ENCODER]}


def shipped_encoder_path(family: str) -> Path:
    """The shipped LTLBootcamp encoder of a world family ("letter", "zone")."""
    return DATA_DIR / f"ltl2action_encoder_{family}.msgpack"


def save_encoder(path: str | Path, params: Any, meta: dict[str, Any]) -> None:
    """Write R-GCN parameters (`encoder_params(...)`) and how they were made (`meta`)."""
    save_params(path, params, meta)


def load_encoder(family_or_path: str | Path, num_propositions: int) -> Any:
    """R-GCN parameters for `num_propositions` propositions: the shipped encoder of a world
    family ("letter", "zone") or a file saved by `save_encoder`.

    Raises:
        ValueError: no such file, no R-GCN parameters in it, or made for another number of
            propositions.
    """
    path, stored, width = load_encoder_file(family_or_path, shipped_encoder_path, "ltl2action",
                                            "LTL2Action", "Dense_0")
    if width != num_features(num_propositions):
        raise ValueError(f"the encoder at {path} reads {width} formula tokens; "
                         f"{num_propositions} propositions need {num_features(num_propositions)}")
    return jax.tree.map(jnp.asarray, stored)
