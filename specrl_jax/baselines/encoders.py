"""Observation encoders chosen by the kind of each observation part (`env.obs_kinds`), never by
env ID: a method sees `{"grid": ..., "vector": ..., "image": ...}` and the encoders below.

The paper's encoders: a CNN for grid maps (channels 16, 32, 64, kernel 2x2), an MLP [128, 64]
(Tanh) for LiDAR, range-bearing and robot-sensor vectors, and a CNN for camera images (channels
16, 32, 64, 64, 32, kernel 5x5, stride 2, padding 1). Their outputs are concatenated.
"""

from __future__ import annotations

from collections.abc import Mapping

import flax.linen as nn
import jax
import jax.numpy as jnp

from specrl_jax.baselines.ppo.networks import COMPUTE_DTYPES, MLP, LetterCNN, PatchConv

#: world observation kinds -> the encoder part they feed
PART_OF_KIND = {"grid": "grid", "lidar": "vector", "range_bearing": "vector", "vector": "vector",
                "image": "image"}


def check_kinds(obs_kinds: Mapping[str, str]) -> None:
    """Raise a clear error for an observation part that no encoder reads."""
    unknown = {key: kind for key, kind in obs_kinds.items() if kind not in PART_OF_KIND}
    if unknown:
        raise ValueError(
            f"no observation encoder for {unknown}; encoders exist for the kinds "
            f"{sorted(PART_OF_KIND)}"
        )


def check_image_dtype(image_dtype: str) -> str:
    """`image_dtype` (the image CNN's convolutions: float32, the original's, or bfloat16), or a
    clear error naming the accepted values."""
    if image_dtype not in COMPUTE_DTYPES:
        raise ValueError(f"image_dtype={image_dtype!r}; choose one of {', '.join(COMPUTE_DTYPES)} "
                         "(the image CNN's convolutions; bfloat16 halves their memory traffic)")
    return image_dtype


def obs_parts(obs: Mapping[str, jax.Array], obs_kinds: Mapping[str, str],
              skip: tuple[str, ...] = ()) -> dict[str, jax.Array]:
    """A world observation (one env) -> encoder parts: grid parts stacked on the channel axis
    (float32[V, V, C]), vector-like parts flattened and concatenated (float32[D]), the image
    (uint8[H, W, 3]). Keys in `skip` are left out."""
    grids, vectors, parts = [], [], {}
    for key in sorted(obs):
        if key in skip:
            continue
        part = PART_OF_KIND[obs_kinds[key]]
        if part == "grid":
            grids.append(obs[key].astype(jnp.float32))
        elif part == "vector":
            vectors.append(obs[key].astype(jnp.float32).reshape(-1))
        else:
            parts["image"] = obs[key]
    if grids:
        parts["grid"] = jnp.concatenate(grids, axis=-1)
    if vectors:
        parts["vector"] = jnp.concatenate(vectors, axis=-1)
    return parts


class ImageCNN(nn.Module):
    """Conv 5x5, stride 2, padding 1, ReLU, channels (16, 32, 64, 64, 32), on uint8[..., H, W, 3]
    scaled to [0, 1]; flattened. `conv`, `compute_dtype`: `PatchConv`'s."""

    channels: tuple[int, ...] = (16, 32, 64, 64, 32)
    conv: str = "auto"
    compute_dtype: str = "float32"

    @nn.compact
    def __call__(self, image: jax.Array) -> jax.Array:
        x = image.astype(jnp.float32) / 255.0
        batch = x.shape[:-3]
        x = x.reshape(-1, *x.shape[-3:])
        for i, width in enumerate(self.channels):
            conv = PatchConv(width, size=5, stride=2, padding=1, conv=self.conv,
                             compute_dtype=self.compute_dtype, name=f"Conv_{i}")
            x = nn.relu(conv(x))
        return x.reshape(*batch, -1)


class ObsEncoder(nn.Module):
    """Embeds the parts of `obs_parts`: grid -> CNN, vector -> MLP `vector_features` Tanh (no
    features: the vector as it is), image -> CNN (its convolutions in `image_dtype`); the
    embeddings concatenated (in the order grid, vector, image)."""

    vector_features: tuple[int, ...] = (128, 64)
    image_dtype: str = "float32"

    @nn.compact
    def __call__(self, parts: Mapping[str, jax.Array]) -> jax.Array:
        out = []
        if "grid" in parts:
            out.append(LetterCNN()(parts["grid"]))
        if "vector" in parts:
            out.append(MLP(self.vector_features, "tanh")(parts["vector"]))
        if "image" in parts:
            out.append(ImageCNN(compute_dtype=self.image_dtype)(parts["image"]))
        return jnp.concatenate(out, axis=-1)
