"""Flax building blocks shared by the baselines: MLPs, the LetterWorld CNN, action distributions
and the heads every method returns.

Sizes are the benchmark's shared ones: actor MLP [64, 64, 64], critic [64, 64], LetterWorld CNN
channels [16, 32, 64] with 2x2 kernels. Dense layers use orthogonal weights (gain 1) as the
reference implementations do.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import cache, partial
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct
from jax.custom_batching import custom_vmap

Activation = Callable[[jax.Array], jax.Array]
ACTIVATIONS: dict[str, Activation] = {
    "relu": nn.relu,
    "tanh": nn.tanh,
    "softplus": nn.softplus,
    "identity": lambda x: x,
}


def unit_columns(key: jax.Array, shape: Sequence[int], dtype: jnp.dtype = jnp.float32) -> jax.Array:
    """LTL2Action's and RAD-Embeddings' `init_params` for linear layers: N(0, 1) weights with each
    output unit's weight vector (a column of a flax kernel [in, out]) scaled to unit L2 norm."""
    w = jax.random.normal(key, shape, dtype)
    return w / jnp.linalg.norm(w, axis=0, keepdims=True)


def dense(features: int, gain: float = 1.0) -> nn.Dense:
    return nn.Dense(features, kernel_init=nn.initializers.orthogonal(gain))


class MLP(nn.Module):
    """Dense layers with `activation` after each hidden layer (and after the last if `final`)."""

    features: Sequence[int]
    activation: str = "relu"
    final: bool = True

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for i, width in enumerate(self.features):
            x = dense(width)(x)
            if self.final or i < len(self.features) - 1:
                x = act(x)
        return x


class PatchConv(nn.Module):
    """A square convolution on `float[..., H, W, C]` -> `[..., H', W', features]` with
    H' = (H + 2 padding - size) // stride + 1, computed as one matmul over the size x size
    strided views of the input.

    With a batch of parameters (`vmap` over seeds) the library convolution's weight gradient
    becomes a batch-grouped convolution, which XLA runs far slower than this batched matmul (an
    epoch of the 5-seed 64 x 64 image update on an H200: 13.3 s against 0.90 s); on XLA:CPU its
    backward pass dominates a PPO update even for one seed (2x2 kernels, 128 images: 36-78 ms
    against 1.7-4.3 ms). The patch matrix holds size^2 x C floats per output pixel. Parameters
    are `nn.Conv`'s (`kernel [size, size, C, features]` LeCun-normal, `bias` zeros), so
    checkpoints of either load into the other.

    `conv` picks how it runs, all with the same parameters and the same function:
    - "patch": the patch matmul, forward and backward.
    - "library_forward": the library convolution's forward, which holds only the layer's input
      for the backward pass; that pass rebuilds the patch matrix and is the patch matmul's. Under
      `vmap` on a GPU the library's forward is the faster (the paper's image CNN, 5 seeds x 2,048
      images of 64 x 64 on an H200: 6.0 ms against 13.9 ms; `benchmarks/lab/image_conv.py`); in
      GenZ-LTL's side-by-side image training loop the faster rollout and the slower update epochs
      cancel (results.md, Training speed).
    - "auto" (`auto_conv`): the library convolution off the CPU, forward and backward, except for
      the gradient of a batch of parameters (`vmap` over seeds), which is the patch matmul's; the
      patch matmul on XLA:CPU. Seeds that learn in turn (`PPOConfig.learn_seeds_in_turn`) take
      the library's gradient, seeds side by side the patch matmul's.
    "library_forward" and "auto" differentiate in reverse mode only, once (`jax.custom_vjp`).

    `compute_dtype` "bfloat16" runs the convolution on bfloat16 copies of the input and the
    kernel with a bfloat16 output, so the gradient's convolutions run in bfloat16 too (half the
    memory traffic); the parameters, the bias and what follows stay float32.
    """

    features: int
    size: int = 2
    stride: int = 1
    padding: int = 0
    conv: str = "patch"
    compute_dtype: str = "float32"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        k = self.size
        if self.conv not in CONVOLUTIONS:
            raise ValueError(f"conv={self.conv!r}; choose one of {', '.join(CONVOLUTIONS)}")
        if self.compute_dtype not in COMPUTE_DTYPES:
            raise ValueError(f"compute_dtype={self.compute_dtype!r}; choose one of "
                             f"{', '.join(COMPUTE_DTYPES)}")
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (k, k, x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        dtype = COMPUTE_DTYPES[self.compute_dtype]
        y = CONVOLUTIONS[self.conv](x.astype(dtype), kernel.astype(dtype), self.stride, self.padding)
        return y.astype(jnp.float32) + bias


def patch_conv(x: jax.Array, kernel: jax.Array, stride: int, padding: int) -> jax.Array:
    """`float[..., H, W, C]`, `kernel [k, k, C, F]` -> `[..., H', W', F]` as the patch matmul."""
    patches = patch_matrix(x, kernel.shape[0], stride, padding)
    return patches @ kernel.reshape(-1, kernel.shape[-1])


def library_conv(x: jax.Array, kernel: jax.Array, stride: int, padding: int) -> jax.Array:
    """`patch_conv`'s convolution as `lax.conv_general_dilated` (what `flax.linen.Conv` calls)."""
    conv_output_size(x.shape[-3:-1], kernel.shape[0], stride, padding)
    y = jax.lax.conv_general_dilated(x.reshape(-1, *x.shape[-3:]), kernel, (stride, stride),
                                     ((padding, padding),) * 2, dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return y.reshape(*x.shape[:-3], *y.shape[1:])


@partial(jax.custom_vjp, nondiff_argnums=(2, 3))
def library_forward_conv(x: jax.Array, kernel: jax.Array, stride: int, padding: int) -> jax.Array:
    """`library_conv` forward, `patch_conv` backward (recomputed from the saved input)."""
    return library_conv(x, kernel, stride, padding)


def _library_forward(x, kernel, stride, padding):
    return library_conv(x, kernel, stride, padding), (x, kernel)


def _vjp(conv: Callable, stride: int, padding: int) -> Callable:
    """`(x, kernel, g) -> (dx, dkernel)` of the convolution `conv`."""
    return lambda x, kernel, g: jax.vjp(partial(conv, stride=stride, padding=padding),
                                        x, kernel)[1](g)


def _patch_backward(stride, padding, saved, g):
    return _vjp(patch_conv, stride, padding)(*saved, g)


library_forward_conv.defvjp(_library_forward, _patch_backward)


def _forward_here(x: jax.Array, kernel: jax.Array, stride: int, padding: int) -> jax.Array:
    return jax.lax.platform_dependent(
        x, kernel, cpu=partial(patch_conv, stride=stride, padding=padding),
        default=partial(library_conv, stride=stride, padding=padding))


@cache
def _auto_gradient(stride: int, padding: int) -> Callable:
    """`(x, kernel, g) -> (dx, dkernel)`: the library's on one set of parameters off the CPU,
    the patch matmul's on the CPU and under `vmap` (a batch of parameters)."""
    patch_vjp, library_vjp = _vjp(patch_conv, stride, padding), _vjp(library_conv, stride, padding)

    @custom_vmap
    def gradient(x, kernel, g):
        return jax.lax.platform_dependent(x, kernel, g, cpu=patch_vjp, default=library_vjp)

    @gradient.def_vmap
    def batched(axis_size, in_batched, x, kernel, g):
        args = [a if b else jnp.broadcast_to(a, (axis_size, *a.shape))
                for a, b in zip((x, kernel, g), in_batched)]
        return jax.vmap(patch_vjp)(*args), (True, True)

    return gradient


@partial(jax.custom_vjp, nondiff_argnums=(2, 3))
def auto_conv(x: jax.Array, kernel: jax.Array, stride: int, padding: int) -> jax.Array:
    """`patch_conv`'s convolution, run where each part is fast (`PatchConv`'s "auto")."""
    return _forward_here(x, kernel, stride, padding)


def _auto_forward(x, kernel, stride, padding):
    return _forward_here(x, kernel, stride, padding), (x, kernel)


def _auto_backward(stride, padding, saved, g):
    return _auto_gradient(stride, padding)(*saved, g)


auto_conv.defvjp(_auto_forward, _auto_backward)

#: `PatchConv.conv`'s choices
CONVOLUTIONS: dict[str, Callable] = {"patch": patch_conv, "library_forward": library_forward_conv,
                                     "auto": auto_conv}
COMPUTE_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}


def patch_matrix(x: jax.Array, size: int, stride: int, padding: int) -> jax.Array:
    """`float[..., H, W, C]` -> `[..., H', W', size * size * C]`: the size x size strided views of
    the zero-padded input side by side, in (dy, dx) row-major order, matching a
    `[size, size, C, F]` kernel reshaped to `[size * size * C, F]`."""
    k, s, p = size, stride, padding
    rows, cols = conv_output_size(x.shape[-3:-1], k, s, p)
    if p:
        x = jnp.pad(x, [(0, 0)] * (x.ndim - 3) + [(p, p), (p, p), (0, 0)])
    views = [x[..., dy:dy + s * (rows - 1) + 1:s, dx:dx + s * (cols - 1) + 1:s, :]
             for dy in range(k) for dx in range(k)]
    return jnp.concatenate(views, axis=-1)


def conv_output_size(image: Sequence[int], size: int, stride: int, padding: int) -> tuple[int, int]:
    """(H', W') of a size x size convolution on an (H, W) `image`; a clear error where none fits."""
    rows, cols = ((n + 2 * padding - size) // stride + 1 for n in image)
    if rows < 1 or cols < 1:
        raise ValueError(f"a {size}x{size} convolution (stride {stride}, padding {padding}) needs an "
                         f"input of at least {size - 2 * padding} x {size - 2 * padding}; got "
                         f"{image[0]} x {image[1]} (a smaller image or grid than the network takes)")
    return rows, cols


class LetterCNN(nn.Module):
    """3 x Conv(2x2, VALID) + ReLU on `float[..., V, V, C]`, flattened (7x7 -> 4*4*64 = 1024)."""

    channels: Sequence[int] = (16, 32, 64)

    @nn.compact
    def __call__(self, image: jax.Array) -> jax.Array:
        x = image.astype(jnp.float32)
        for i, width in enumerate(self.channels):
            x = nn.relu(PatchConv(width, name=f"Conv_{i}")(x))
        return x.reshape(*x.shape[:-3], -1)


@struct.dataclass
class Categorical:
    """Categorical over the last axis of `logits` (masked entries hold a large negative value)."""

    logits: jax.Array
    action_dims = 1  # one choice per sample

    def log_probs(self) -> jax.Array:
        return jax.nn.log_softmax(self.logits, axis=-1)

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.categorical(key, self.logits, axis=-1).astype(jnp.int32)

    def mode(self) -> jax.Array:
        return jnp.argmax(self.logits, axis=-1).astype(jnp.int32)

    def log_prob(self, action: jax.Array) -> jax.Array:
        return jnp.take_along_axis(self.log_probs(), action[..., None].astype(jnp.int32), -1)[..., 0]

    def entropy(self) -> jax.Array:
        log_p = self.log_probs()
        return -jnp.sum(jnp.where(jnp.exp(log_p) > 0, jnp.exp(log_p) * log_p, 0.0), axis=-1)


@struct.dataclass
class DiagGaussian:
    """Independent normals over the last axis; log-probs and entropies are summed over it."""

    mean: jax.Array
    std: jax.Array

    @property
    def action_dims(self) -> int:
        return self.mean.shape[-1]

    def sample(self, key: jax.Array) -> jax.Array:
        return self.mean + self.std * jax.random.normal(key, self.mean.shape)

    def mode(self) -> jax.Array:
        return self.mean

    def log_prob(self, action: jax.Array) -> jax.Array:
        z = (action - self.mean) / self.std
        return jnp.sum(-0.5 * z**2 - jnp.log(self.std) - 0.5 * jnp.log(2 * jnp.pi), axis=-1)

    def entropy(self) -> jax.Array:
        return jnp.sum(0.5 + 0.5 * jnp.log(2 * jnp.pi) + jnp.log(self.std), axis=-1)


MASKED_LOGIT = -1e9


class DiscreteHead(nn.Module):
    """Logits over `num_actions`; entries where `mask` is False are pushed to `MASKED_LOGIT`."""

    num_actions: int

    @nn.compact
    def __call__(self, x: jax.Array, mask: jax.Array | None = None) -> Categorical:
        logits = dense(self.num_actions, gain=0.01)(x)
        if mask is not None:
            logits = jnp.where(mask, logits, MASKED_LOGIT)
        return Categorical(logits)


class GaussianHead(nn.Module):
    """DeepLTL's continuous head: mean `tanh(Wx)`, std `softplus(tanh(W'x)) + 1e-3`."""

    action_dim: int

    @nn.compact
    def __call__(self, x: jax.Array) -> DiagGaussian:
        mean = nn.tanh(dense(self.action_dim)(x))
        std = nn.softplus(nn.tanh(dense(self.action_dim)(x))) + 1e-3
        return DiagGaussian(mean, std)


@struct.dataclass
class EpsilonGaussian:
    """DeepLTL's mixed distribution over `float32[..., D + 1]`: the last entry is 1 for the epsilon
    action (probability `p_epsilon`, only where `allowed`), else 0 and the first D entries are
    drawn from `DiagGaussian(mean, std)`."""

    gaussian: DiagGaussian
    p_epsilon: jax.Array  # float32[...]
    allowed: jax.Array  # bool[...]

    @property
    def action_dims(self) -> int:
        return self.gaussian.action_dims

    def _p(self) -> jax.Array:
        return jnp.where(self.allowed, self.p_epsilon, 0.0)

    def sample(self, key: jax.Array) -> jax.Array:
        key_eps, key_move = jax.random.split(key)
        eps = jax.random.uniform(key_eps, self.p_epsilon.shape) < self._p()
        return jnp.concatenate([self.gaussian.sample(key_move), eps[..., None].astype(jnp.float32)], -1)

    def mode(self) -> jax.Array:
        eps = self.allowed & (self.p_epsilon > 0.7)
        return jnp.concatenate([self.gaussian.mean, eps[..., None].astype(jnp.float32)], -1)

    def log_prob(self, action: jax.Array) -> jax.Array:
        eps = action[..., -1] > 0.5
        move = self.gaussian.log_prob(action[..., :-1]) + jnp.where(
            self.allowed, jnp.log1p(-self.p_epsilon), 0.0)
        return jnp.where(eps, jnp.log(self.p_epsilon), move)

    def entropy(self) -> jax.Array:
        return self.gaussian.entropy() * (1.0 - self._p())


class EpsilonGaussianHead(nn.Module):
    """`GaussianHead` plus DeepLTL's epsilon head `p = clip(sigmoid(Wx), 1e-3, 1 - 1e-3)`."""

    action_dim: int

    @nn.compact
    def __call__(self, x: jax.Array, allowed: jax.Array) -> EpsilonGaussian:
        p_epsilon = jnp.clip(nn.sigmoid(dense(1)(x)[..., 0]), 1e-3, 1 - 1e-3)
        return EpsilonGaussian(GaussianHead(self.action_dim)(x), p_epsilon, allowed)


class PolicyOutput(NamedTuple):
    """What every method's network returns for a batch of observations `[..., ...]`.

    `value` float32[...]; `cost_value` and `multiplier` float32[...] (zeros for unconstrained methods).
    """

    pi: Categorical | DiagGaussian | EpsilonGaussian
    value: jax.Array
    cost_value: jax.Array
    multiplier: jax.Array


def critic(features: Sequence[int], activation: str, final: str = "identity") -> nn.Module:
    """`[emb, *features, 1]` value MLP; `final` is applied to the scalar output."""
    return nn.Sequential([MLP(tuple(features) + (1,), activation, final=False), ACTIVATIONS[final]])
