"""Embedding tables for RAD-Embeddings: the frozen encoder's embedding of every reachable state of
a bank's conjunctions, encoded once, so that the task loop looks an embedding up instead of
running the encoder (8 GATv2 rounds over a graph of up to ~45 nodes) for every env at every step.

The encoder is frozen, so the embedding of conjunction k at states q int32[N] is a function of
(k, q) alone. The host enumerates the state tuples reachable from each conjunction's start
(breadth-first under every symbol of the alphabet, with the bank's transition arrays), the
encoder embeds them in batches on the default device, and the table keeps the rows float32[R, E].

Lookup: conjunction k's tuples are numbered in mixed radix (digit n below
max(num_states[k, n], 1): an unused conjunct, always in state 0, adds nothing) after the tuples
of conjunctions 0 .. k-1, a position in the bank's product space of M tuples; `row_of` int32[M]
maps a position to its row (-1: unreachable). A lookup is a few gathers, with no loop (a binary
search would be a while loop inside every env step). On the default banks of 4,096 conjunctions
(graphs of at most 40 nodes) M is 1.4x R on LetterWorld's alphabet, 2.2x on ZoneEnv's.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from tqdm.auto import tqdm

from specrl_jax.automata.rad_sampler import DFABank

#: rows above which a bank is embedded per step instead (128 MiB of float32[32] rows)
MAX_TABLE_ROWS = 1 << 20
#: positions of the product space allowed per row of the budget: the int32 position map is then
#: no larger than a table of float32[32] rows
POSITIONS_PER_ROW = 32
#: tuples embedded per call of the encoder while building a table
ENCODE_CHUNK = 2048

Array = np.ndarray | jax.Array
#: (index int32[B], q int32[B, N]) -> float32[B, E]: the frozen encoder over a batch of tuples
Encode = Callable[[jax.Array, jax.Array], jax.Array]


@struct.dataclass
class EmbeddingTable:
    """The embeddings of a bank's reachable state tuples and the map from tuples to rows.

    Attributes:
        rows: float32[R, E] one embedding per reachable (conjunction, state tuple).
        row_of: int32[M] the row of each position of the product space (-1: unreachable).
        place: int32[K, N] the place value of conjunct n's state in conjunction k's positions.
        base: int32[K] the position of conjunction k's start tuple (all states 0).
    """

    rows: jax.Array
    row_of: jax.Array
    place: jax.Array
    base: jax.Array

    @property
    def num_rows(self) -> int:
        return int(self.rows.shape[0])


def product_space(num_states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mixed-radix numbering of a bank's state tuples from `num_states` int[K, N].

    Returns:
        place int64[K, N] (conjunct n's place value), base int64[K] (conjunction k's first
        position) and radix int64[K, N] (conjunct n's digits).
    """
    radix = np.maximum(np.asarray(num_states, np.int64), 1)
    suffix = np.cumprod(radix[:, ::-1], axis=1)[:, ::-1]  # [k, n]: product of radix[k, n:]
    place = np.concatenate([suffix[:, 1:], np.ones_like(suffix[:, :1])], axis=1)
    base = np.cumsum(suffix[:, 0]) - suffix[:, 0]
    return place, base, radix


def num_positions(base: np.ndarray, radix: np.ndarray) -> int:
    """M, the tuples of the product space of `product_space`'s `base` and `radix`."""
    return int(base[-1] + radix[-1].prod())


def positions(place: Array, base: Array, index: Array, q: Array) -> Array:
    """The product-space positions int[...] of tuples `q` int[..., N] of conjunctions `index`
    int[...] (numpy or jax arrays alike)."""
    return base[index] + (q * place[index]).sum(axis=-1)


def reachable_positions(bank: DFABank) -> np.ndarray:
    """bool[M]: the product-space positions of the tuples reachable from each conjunction's start
    tuple under the bank's alphabet (breadth-first, on the host)."""
    delta = np.asarray(bank.delta, np.int64)
    num, conjuncts, _, symbols = delta.shape
    place, base, radix = product_space(np.asarray(bank.num_states))
    seen = np.zeros(num_positions(base, radix), bool)
    index, q = np.arange(num), np.zeros((num, conjuncts), np.int64)
    seen[positions(place, base, index, q)] = True
    while index.size:
        successors = delta[index[:, None, None], np.arange(conjuncts), q[:, None, :],
                           np.arange(symbols)[:, None]]  # [F, A, N]
        index, q = np.repeat(index, symbols), successors.reshape(-1, conjuncts)
        found, first = np.unique(positions(place, base, index, q), return_index=True)
        new = ~seen[found]
        seen[found[new]] = True
        index, q = index[first[new]], q[first[new]]
    return seen


def tuples_at(num_states: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (index int32[R], q int32[R, N]) at product-space positions `at` int[R]."""
    place, base, radix = product_space(num_states)
    index = np.searchsorted(base, at, side="right") - 1
    q = (at - base[index])[:, None] // place[index] % radix[index]
    return index.astype(np.int32), q.astype(np.int32)


def encode_tuples(encode: Encode, index: np.ndarray, q: np.ndarray,
                  chunk: int = ENCODE_CHUNK) -> jax.Array:
    """float32[R, E]: `encode` of every (index int[R], q int[R, N]), `chunk` tuples per jitted
    call (the last chunk padded with the first tuple, so one compilation serves)."""
    batch = jax.jit(encode)
    count = index.shape[0]
    pad = -count % chunk
    index = np.concatenate([index, np.full(pad, index[0], index.dtype)])
    q = np.concatenate([q, np.repeat(q[:1], pad, axis=0)])
    starts = range(0, count + pad, chunk)
    # minutes on a laptop CPU for a default bank: show progress on a terminal
    shown = tqdm(starts, desc="RAD: encoding reachable DFA states", unit="chunk",
                 disable=True if len(starts) < 8 else None)
    out = [jax.block_until_ready(batch(index[i:i + chunk], q[i:i + chunk])) for i in shown]
    return jnp.concatenate(out)[:count]


def build_table(bank: DFABank, encode: Encode, max_rows: int = MAX_TABLE_ROWS,
                chunk: int = ENCODE_CHUNK) -> EmbeddingTable:
    """The embedding table of every reachable state tuple of `bank` by the batch encoder `encode`.

    Raises:
        ValueError: the bank has more than `max_rows` reachable tuples, or a product space over
            `POSITIONS_PER_ROW * max_rows` tuples or int32's range (checked before the search).
    """
    place, base, radix = product_space(np.asarray(bank.num_states))
    space, budget = num_positions(base, radix), POSITIONS_PER_ROW * max_rows
    if space > min(budget, np.iinfo(np.int32).max):  # positions are int32 inside jit
        raise ValueError(f"the bank's {bank.size} conjunctions have {space:,} state tuples, over "
                         f"the table's budget of {budget:,} ({POSITIONS_PER_ROW} per row of "
                         f"max_rows={max_rows:,}) or int32's range")
    seen = reachable_positions(bank)
    count = int(seen.sum())
    if count > max_rows:
        raise ValueError(f"the bank's {bank.size} conjunctions reach {count:,} state tuples, over "
                         f"the table's budget of max_rows={max_rows:,}")
    at = np.flatnonzero(seen)
    index, q = tuples_at(np.asarray(bank.num_states), at)
    row_of = np.full(space, -1, np.int32)
    row_of[at] = np.arange(count, dtype=np.int32)
    return EmbeddingTable(encode_tuples(encode, index, q, chunk), jnp.asarray(row_of),
                          jnp.asarray(place, jnp.int32), jnp.asarray(base, jnp.int32))


def lookup(table: EmbeddingTable, index: jax.Array, q: jax.Array) -> jax.Array:
    """float32[..., E]: the embedding of conjunction `index` int32[...] at reachable states `q`
    int32[..., N] (an unreachable tuple reads the wrong row: the task loop reaches none)."""
    return table.rows[table.row_of[positions(table.place, table.base, index, q)]]
