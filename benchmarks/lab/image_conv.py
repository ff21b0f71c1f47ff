"""The image CNN's convolution under a batch of parameters: which implementation a seed-batched
(`vmap`) PPO should use.

The paper's image CNN (`encoders.ImageCNN`: 5 layers, kernel 5, stride 2, padding 1) is timed for
`--seeds` parameter sets side by side (`vmap`), as training runs them, or one after the other
(`--in-turn`: `lax.map`, as seeds that learn in turn take their gradients), in these
implementations:

  library  `lax.conv_general_dilated` (what `flax.linen.Conv` calls); under `vmap` its forward is
           a feature-grouped convolution, its weight gradient a batch-grouped one
  patches  `PatchConv`, the package's: one matmul over the strided views (the patch matrix)
  hybrid   the library's forward and input gradient, the weight gradient as the patch matmul
           (`jax.custom_vjp`)
  shifted  the sum over the kernel's size x size offsets of one matmul per strided view (no patch
           matrix: XLA may fuse each view into its matmul)
  recompute  `ImageCNN(conv="library_forward")`: the library's forward, saving only each layer's
           input; the backward pass is the patch matmul's, its patch matrix rebuilt from that
           input (`jax.custom_vjp`)
  auto     `ImageCNN(conv="auto")`, the package's default: the library's forward and gradient for
           one set of parameters, the patch matmul's gradient under `vmap` (on a GPU)
  patches_bf16  `patches` with the patch matrix and the kernel in bfloat16, accumulated in float32
           (half the patch matrix's memory traffic; gradients within bfloat16's precision)
  library_bf16  `library` with the input, the kernel and the output in bfloat16 (the gradient's
           convolutions in bfloat16 too; with `--in-turn`, the lever for seeds that learn in
           turn, whose update is the library convolution's)

For each `--cases SIZE:IMAGES` (IMAGES per seed) it times the forward pass (the rollout's policy
inference) and the value and gradient of a scalar loss (a minibatch step), median of `--repeats`
calls after a warm-up, reads each program's temporary memory from XLA's memory analysis, and
checks that every implementation's gradients equal the library's (an error otherwise). An implementation that runs
out of device memory is recorded as such. One JSON row per case and implementation
(`benchmarks/harness.py`; appended to `--out` if given).

    python benchmarks/lab/image_conv.py --seeds 5 --cases 64:2048 256:512
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

from specrl_jax.baselines.encoders import ImageCNN
from specrl_jax.baselines.ppo import networks
from specrl_jax.baselines.ppo.networks import patch_matrix

SIZE, STRIDE, PADDING = 5, 2, 1


def library_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    return networks.library_conv(x, kernel, STRIDE, PADDING)


@jax.custom_vjp
def hybrid_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    return library_conv(x, kernel)


def _hybrid_forward(x, kernel):
    return library_conv(x, kernel), (x, kernel)


def _hybrid_backward(saved, g):
    x, kernel = saved
    (dx,) = jax.vjp(lambda x: library_conv(x, kernel), x)[1](g)
    dk = jnp.einsum("nhwp,nhwf->pf", patch_matrix(x, SIZE, STRIDE, PADDING), g).reshape(kernel.shape)
    return dx, dk


hybrid_conv.defvjp(_hybrid_forward, _hybrid_backward)


def shifted_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    p = PADDING
    padded = jnp.pad(x, [(0, 0)] * (x.ndim - 3) + [(p, p), (p, p), (0, 0)])
    rows, cols = networks.conv_output_size(x.shape[-3:-1], SIZE, STRIDE, PADDING)
    out = 0.0
    for dy in range(SIZE):
        for dx in range(SIZE):
            view = padded[..., dy:dy + STRIDE * (rows - 1) + 1:STRIDE, dx:dx + STRIDE * (cols - 1) + 1:STRIDE, :]
            out = out + view @ kernel[dy, dx]
    return out


def patches_bf16_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    patches = patch_matrix(x.astype(jnp.bfloat16), SIZE, STRIDE, PADDING)
    weights = kernel.astype(jnp.bfloat16).reshape(-1, kernel.shape[-1])
    return jnp.matmul(patches, weights, preferred_element_type=jnp.float32)


def library_bf16_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    # as `PatchConv(compute_dtype="bfloat16")`: a bfloat16 output (cast after), so the cotangent
    # reaches the gradient's convolutions in bfloat16 too
    return library_conv(x.astype(jnp.bfloat16), kernel.astype(jnp.bfloat16)).astype(jnp.float32)


def cnn_with(conv: Callable[[jax.Array, jax.Array], jax.Array]) -> Callable:
    """`ImageCNN`'s function with its convolution replaced by `conv` (the same parameters)."""

    def apply(params: Any, image: jax.Array) -> jax.Array:
        x = image.astype(jnp.float32) / 255.0
        for i in range(len(ImageCNN.channels)):
            layer = params["params"][f"Conv_{i}"]
            x = jax.nn.relu(conv(x, layer["kernel"]) + layer["bias"])
        return x.reshape(x.shape[0], -1)

    return apply


IMPLEMENTATIONS = {
    "library": cnn_with(library_conv),
    "patches": ImageCNN(conv="patch").apply,
    "auto": ImageCNN(conv="auto").apply,
    "hybrid": cnn_with(hybrid_conv),
    "shifted": cnn_with(shifted_conv),
    "recompute": ImageCNN(conv="library_forward").apply,
    "patches_bf16": cnn_with(patches_bf16_conv),
    "library_bf16": cnn_with(library_bf16_conv),
}
#: largest relative gradient difference to the library's: TF32 matmuls and convolutions on GPUs
#: give about 1e-2; bfloat16 operands (8-bit mantissa) 3e-2 on 32 images a seed, 0.14 on 2
#: (a check that it is the same function; the precision is what the row's figure reports)
TOLERANCE = {"patches_bf16": 0.3, "library_bf16": 0.3}


def programs(apply: Callable, params: Any, images: jax.Array, in_turn: bool) -> dict[str, Any]:
    """The compiled forward and gradient programs of `apply` over the seed axis (`vmap`, or
    `lax.map` if `in_turn`)."""
    def loss(p, x):
        return jnp.sum(jnp.sin(apply(p, x)))

    def over_seeds(fn):
        return (lambda p, x: jax.lax.map(lambda a: fn(*a), (p, x))) if in_turn else jax.vmap(fn)

    forward = jax.jit(over_seeds(apply)).lower(params, images).compile()
    gradient = jax.jit(over_seeds(jax.value_and_grad(loss))).lower(params, images).compile()
    return {"forward": forward, "gradient": gradient}


def median_ms(fn: Callable[[], Any], repeats: int) -> float:
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def temp_gib(compiled: Any) -> float | None:
    memory = compiled.memory_analysis()
    return None if memory is None else round(memory.temp_size_in_bytes / 2**30, 3)


def measure(name: str, seeds: int, size: int, images_per_seed: int, repeats: int,
            reference: Any, in_turn: bool = False) -> tuple[dict[str, Any], Any]:
    """One implementation at one case: its times, memory, gradients' largest relative difference
    to `reference` (the library's, or None), and its gradients."""
    key = jax.random.key(0)
    images = jax.random.randint(key, (seeds, images_per_seed, size, size, 3), 0, 256).astype(jnp.uint8)
    params = jax.vmap(lambda k: ImageCNN().init(k, images[0, :1]))(jax.random.split(key, seeds))
    row: dict[str, Any] = {"implementation": name, "image_size": size, "seeds": seeds,
                           "images_per_seed": images_per_seed, "in_turn": in_turn}
    try:
        compiled = programs(IMPLEMENTATIONS[name], params, images, in_turn)
        row["forward_ms"] = round(median_ms(lambda: compiled["forward"](params, images), repeats), 3)
        row["gradient_ms"] = round(median_ms(lambda: compiled["gradient"](params, images), repeats), 3)
        row["forward_temp_gib"] = temp_gib(compiled["forward"])
        row["gradient_temp_gib"] = temp_gib(compiled["gradient"])
        grads = jax.device_get(compiled["gradient"](params, images)[1])
    except jax.errors.JaxRuntimeError as error:
        if "RESOURCE_EXHAUSTED" not in str(error):
            raise
        row["out_of_memory"] = str(error).splitlines()[0][:200]
        return row, None
    if reference is not None:
        row["gradient_max_rel_diff"] = max(
            float(np.max(np.abs(a - b)) / (np.max(np.abs(b)) + 1e-12))
            for a, b in zip(jax.tree.leaves(grads), jax.tree.leaves(reference), strict=True))
        if row["gradient_max_rel_diff"] > TOLERANCE.get(name, 2e-2):
            raise AssertionError(f"{name}'s gradients differ from the library convolution's: {row}")
    return row, grads


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="parameter sets side by side (vmap)")
    parser.add_argument("--cases", nargs="+", default=["64:2048", "256:512"], metavar="SIZE:IMAGES",
                        help="image size and images per seed")
    parser.add_argument("--implementations", nargs="+", default=list(IMPLEMENTATIONS),
                        choices=list(IMPLEMENTATIONS))
    parser.add_argument("--in-turn", action="store_true",
                        help="the seeds one after the other (lax.map) instead of side by side")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args(argv)
    try:
        args.cases = [tuple(int(v) for v in case.split(":")) for case in args.cases]
    except ValueError:
        parser.error(f"--cases takes SIZE:IMAGES pairs of ints, e.g. 64:2048; got {args.cases}")
    return args


def main() -> None:
    args = parse_args()
    for size, images in args.cases:
        reference = None
        for name in sorted(args.implementations, key=lambda n: n != "library"):
            row, grads = measure(name, args.seeds, size, images, args.repeats, reference, args.in_turn)
            if name == "library":
                reference = grads
            if "out_of_memory" in row:
                value = "out of memory"
            else:
                value = (f"forward {row['forward_ms']:.2f} ms, forward and gradient "
                         f"{row['gradient_ms']:.2f} ms")
            print(f"{size:4} x {size:<4} {images:6} images/seed  {name:9} {value}", flush=True)
            harness.emit(harness.row(f"Image CNN {'in turn' if args.in_turn else 'under vmap'}, {name}, {size}x{size}", value,
                                     args.seeds * images, **row), args.out)


if __name__ == "__main__":
    main()
