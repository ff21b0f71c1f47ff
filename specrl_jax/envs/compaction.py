"""Run an expensive per-item function under `vmap` only on the items that need it.

`where_needed(fn, needs, default, capacities)` is a per-item function: `fn(x)` where
`needs(x)`, else `default(x)`. Called on one item it is a `lax.cond`. Under `vmap` a `cond` would
run both branches on every item; here the batching rule instead gathers the items that need `fn`
into the smallest sub-batch of the fixed sizes `ceil(capacity * B)` that holds them all, runs
`fn` on those only and scatters the results back, runs the largest size over them in turn (a
loop) when more need it than it holds, and runs nothing when none does. Nested `vmap`s (seeds x
envs) are merged into one batch first. An item's result does not depend on which path ran or on the
other items in its batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap


def _need(needs: Callable, x: Any) -> jax.Array:
    need = jnp.asarray(needs(x))
    if need.shape != ():
        raise ValueError(f"`needs` must return one bool per item; got shape {need.shape}")
    return need


def _run_batch(fn: Callable, needs: Callable, default: Callable, capacities: tuple[float, ...],
               x: Any, axes: Any) -> Any:
    """`fn` or `default` per item of `x` (leaves with `axes` 0 carry the batch axis)."""
    need = jax.vmap(lambda item: _need(needs, item), in_axes=(axes,))(x)
    size = need.shape[0]
    fallback = jax.vmap(default, in_axes=(axes,))(x)

    def gathered(slots: int, loop: bool) -> Callable:
        """`fn` on the needing items, `slots` at a time: once, or (`loop`) until all are done."""
        def run():
            order = jnp.nonzero(need, size=size + slots, fill_value=size)[0]  # `size`: empty

            def chunk(start, result):
                index = jax.lax.dynamic_slice(order, (start,), (slots,))
                take = jnp.minimum(index, size - 1)
                sub = jax.tree.map(lambda leaf, axis: leaf if axis is None else leaf[take], x, axes)
                out = jax.vmap(fn, in_axes=(axes,))(sub)
                return jax.tree.map(lambda r, o: r.at[index].set(o, mode="drop"), result, out)

            if not loop:
                return chunk(0, fallback)
            return jax.lax.while_loop(lambda c: c[0] < count,
                                      lambda c: (c[0] + slots, chunk(c[0], c[1])), (0, fallback))[1]
        return run

    tiers = sorted({max(1, math.ceil(c * size)) for c in capacities})
    count = jnp.sum(need)
    tier = jnp.sum(count > jnp.asarray([0, *tiers[:-1]]))  # none, or the smallest that fits
    runs = [gathered(slots, loop=slots == tiers[-1]) for slots in tiers]
    return jax.lax.switch(tier, [lambda: fallback, *runs])


def _batched_runner(fn: Callable, needs: Callable, default: Callable, capacities: tuple[float, ...],
                    treedef: Any, mask: tuple[bool, ...]) -> Callable:
    """A function of `(batched leaves, unbatched leaves)` running `_run_batch`; under a further
    `vmap` it merges the new axis into the batch and calls the runner for the merged mask."""

    @custom_vmap
    def run(batched: list, const: list) -> Any:
        batched_it, const_it = iter(batched), iter(const)
        leaves = [next(batched_it) if m else next(const_it) for m in mask]
        axes = jax.tree.unflatten(treedef, [0 if m else None for m in mask])
        return _run_batch(fn, needs, default, capacities, jax.tree.unflatten(treedef, leaves), axes)

    @run.def_vmap
    def merge(outer: int, in_batched: list, batched: list, const: list):
        batched_outer, const_outer = in_batched
        inner = batched[0].shape[1 if batched_outer[0] else 0]
        batched_it = iter(zip(batched, batched_outer))
        const_it = iter(zip(const, const_outer))
        new_batched, new_const, new_mask = [], [], []
        for m in mask:
            leaf, has_outer = next(batched_it) if m else next(const_it)
            if not m and not has_outer:
                new_const.append(leaf)
                new_mask.append(False)
                continue
            if not has_outer:  # [inner, ...] -> [outer, inner, ...]
                leaf = jnp.broadcast_to(leaf, (outer,) + leaf.shape)
            elif not m:  # [outer, ...] -> [outer, inner, ...]
                leaf = jnp.broadcast_to(leaf[:, None], (outer, inner) + leaf.shape[1:])
            new_batched.append(leaf.reshape((outer * inner,) + leaf.shape[2:]))
            new_mask.append(True)
        runner = _batched_runner(fn, needs, default, capacities, treedef, tuple(new_mask))
        out = runner(new_batched, new_const)
        out = jax.tree.map(lambda y: y.reshape((outer, inner) + y.shape[1:]), out)
        return out, jax.tree.map(lambda _: True, out)

    return run


def where_needed(fn: Callable, needs: Callable, default: Callable,
                 capacities: Sequence[float]) -> Callable:
    """The per-item function `x -> fn(x) if needs(x) else default(x)`.

    Args:
        fn: the expensive per-item function.
        needs: per item, a bool scalar: whether `fn` must run.
        default: per item, the result where `fn` need not run (same structure as `fn`'s).
        capacities: fractions of the batch: under `vmap` over B items, `fn` runs on a gathered
            sub-batch of the smallest `ceil(capacity * B)` that holds every item needing it,
            on the largest size in turn when none holds them, and not at all when no item
            needs it (each size is a program of its own).

    The three functions may close over constants only: a traced value (a batched one above
    all) must come in through `x`. `fn` is traced once per item shape (`jax.jit`) and that
    trace batched for every size and `vmap` level, so it may not depend on state active where
    it is called (a context manager, a patched module) unless it sets that state itself.
    Forward-mode differentiation works; reverse mode does not (`custom_vmap` has no transpose).
    """
    capacities = tuple(float(c) for c in capacities)
    if not capacities or not all(0.0 < c <= 1.0 for c in capacities):
        raise ValueError(f"capacities are fractions of the batch in (0, 1]; got {capacities}")
    fn = jax.jit(fn)

    @custom_vmap
    def one(x: Any) -> Any:
        return jax.lax.cond(_need(needs, x), fn, default, x)

    @one.def_vmap
    def batched(axis_size: int, in_batched: list, x: Any):
        leaves, treedef = jax.tree.flatten(x)
        mask = tuple(bool(b) for b in jax.tree.leaves(in_batched[0]))
        runner = _batched_runner(fn, needs, default, capacities, treedef, mask)
        out = runner([leaf for leaf, m in zip(leaves, mask) if m],
                     [leaf for leaf, m in zip(leaves, mask) if not m])
        return out, jax.tree.map(lambda _: True, out)

    return one


__all__ = ["where_needed"]
