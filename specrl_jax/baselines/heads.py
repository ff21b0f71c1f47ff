"""Network heads shared by the methods that condition on a formula embedding (LTL2Action,
RAD-Embeddings)."""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from specrl_jax.baselines.encoders import ImageCNN
from specrl_jax.baselines.ppo.networks import (
    Categorical,
    GaussianHead,
    LetterCNN,
    PolicyOutput,
    unit_columns,
)


def dense(features: int) -> nn.Dense:
    """A Dense layer initialised as the originals' (unit-norm weight columns, zero bias)."""
    return nn.Dense(features, kernel_init=unit_columns)


def embedding_actor_critic(parts: dict, embedding: jax.Array, num_actions: int,
                           continuous: bool, image_dtype: str = "float32") -> PolicyOutput:
    """The LTL2Action network body (RAD-Embeddings' too); call it inside a compact module.
    Observation encoders by kind (grid CNN, vector MLP [128, 64] ReLU, image CNN) concatenated
    with the spec `embedding` (the image CNN's convolutions in `image_dtype`); actor [64, 64, 64] ReLU then logits (or a Gaussian with Tanh mean
    and state-dependent std); critic [64, 64] Tanh. Dense layers start as the original's."""
    out = []
    if "grid" in parts:
        out.append(LetterCNN()(parts["grid"]))
    if "vector" in parts:
        out.append(nn.relu(dense(64)(nn.relu(dense(128)(parts["vector"])))))
    if "image" in parts:
        out.append(ImageCNN(compute_dtype=image_dtype)(parts["image"]))
    emb = jnp.concatenate([*out, embedding], axis=-1)
    hidden = emb
    for width in (64, 64, 64):
        hidden = nn.relu(dense(width)(hidden))
    pi = GaussianHead(num_actions)(hidden) if continuous else Categorical(dense(num_actions)(hidden))
    value = dense(1)(nn.tanh(dense(64)(nn.tanh(dense(64)(emb)))))[..., 0]
    zeros = jnp.zeros_like(value)
    return PolicyOutput(pi, value, zeros, zeros)
