"""Scoring a chosen few of a policy's candidate subgoals, a chunk at a time (GenZ-LTL, DeepLTL).

A planner scores candidates only when it replans, and only the candidates it may pick. Under
`vmap` a `lax.cond` cannot skip the plan: it runs both branches for every episode and first
copies all its operands, network weights included, once per episode. A `while` loop over the
chosen candidates runs as many turns as the episode needing the most (none at a step where no
episode replans) and holds one chunk of network inputs per episode at a time.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

CHUNK = 4  # candidates scored per turn


def score_chosen(score: Callable[[jax.Array], jax.Array], chosen: jax.Array,
                 chunk: int = CHUNK) -> jax.Array:
    """The scores of the `chosen` candidates, -inf for the others (trace-time; `vmap` it).

    Args:
        score: candidate ids int32[chunk] -> float32[chunk]; ids past the chosen ones repeat
            the last candidate and their scores are dropped.
        chosen: bool[N], the candidates to score.
        chunk: candidates per turn of the loop (the memory of one turn).

    Returns:
        float32[N].
    """
    num = chosen.shape[0]
    order = jnp.nonzero(chosen, size=-(-num // chunk) * chunk, fill_value=num)[0]

    def turn(loop):
        index, scores = loop
        ids = jax.lax.dynamic_slice(order, (index * chunk,), (chunk,))
        return index + 1, scores.at[ids].set(score(jnp.minimum(ids, num - 1)), mode="drop")

    # The loop counts turns in steps of one: XLA (jaxlib 0.10.2, CPU) runs `i < 1` with
    # `i += chunk` zero times when the bound is a compile-time constant (e.g. one candidate in a
    # spec known at trace time), and every score stayed -inf.
    turns = -(-chosen.sum() // chunk)
    start = (jnp.int32(0), jnp.full(num, -jnp.inf, jnp.float32))
    return jax.lax.while_loop(lambda loop: loop[0] < turns, turn, start)[1]
