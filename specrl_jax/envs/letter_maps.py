"""LetterWorld maps: exact uniform sampling of the original's valid maps, inside `jit`.

A map is valid (as in the original) iff the empty cells, the start (0, 0) included, form one
4-connected component of the torus and every letter cell has an empty 4-neighbour. Validity
depends only on which cells are occupied, so a uniform valid map is a uniform valid set of
`k` cells plus a uniform labelling of those cells with the letter multiset.

Sets are drawn by rejection, in rounds of `R` proposals. A board is a bitboard `uint32[N]`
(bit c of row r is cell (r, c)), so one 4-neighbour dilation on the torus is two bit rotations
and two row rolls. Each proposal occupies every non-start cell independently with probability
p = j / 2^m (built from m random words by bitwise and/or): conditioned on holding exactly k cells,
such a board is a uniform k-subset whatever p is. Boards with k cells and no cell without an
empty neighbour (a necessary condition, cheap) are compacted into `J` slots and flood-filled; the
first valid slot is accepted, otherwise another round runs. The accepted set is exactly uniform
over valid sets (the examined boards are i.i.d. given that they pass the cheap filter).

Rejection needs valid sets to be common enough: `valid_rate` estimates, by a bounded Monte Carlo
on the host, the fraction of uniform k-subsets that are valid, and `LetterConfig` rejects a
configuration below `MIN_VALID_RATE`. The loop is bounded by `MapSpec.round_limit` rounds,
after which (probability below e^-40 at the minimum rate) it returns `MapSpec.fallback`, a fixed
valid set found by the estimate, and `base.sampler_check` fails (raised in checked mode).

A map bank (`sample_bank`) holds exactly sampled sets as ordinal grids; `letters_from_bank`
draws one with a random symmetry of the torus that fixes (0, 0) and a fresh uniform labelling:
the opt-in fast reset for auto-resetting batches (docs/fidelity.md).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.base import sampler_check

MAX_GRID_SIZE = 32  # one uint32 word per board row
#: least fraction of uniform placements that must be valid; at this rate an exact reset takes
#: tens of milliseconds on a CPU (15x15, 90 cells: rate 3e-4, 22 ms), far below it, seconds to hours
MIN_VALID_RATE = 1e-4


@dataclass(frozen=True)
class MapSpec:
    """Static description of a map distribution (hashable, derived from a LetterConfig).

    Attributes:
        grid_size: N, the torus is N x N.
        slot_letters: letter index of each of the k letter slots, sorted (the letter multiset).
        fallback: bitboard rows of a valid set, returned if the sampler runs out of rounds
            (None: the last proposal, invalid).
        max_rounds: bound on the rejection rounds (None: `round_limit`'s default).
    """

    grid_size: int
    slot_letters: tuple[int, ...]
    fallback: tuple[int, ...] | None = None
    max_rounds: int | None = None

    @property
    def num_cells(self) -> int:
        return len(self.slot_letters)

    @property
    def row_mask(self) -> int:
        return (1 << self.grid_size) - 1

    @property
    def bernoulli(self) -> tuple[int, int]:
        """(j, m): the per-cell occupancy probability j / 2^m nearest k / (N^2 - 1), m <= 4."""
        free = self.grid_size**2 - 1
        j = min(15, max(1, round(16 * self.num_cells / free)))
        m = 4
        while j % 2 == 0:
            j, m = j // 2, m - 1
        return j, m

    @property
    def count_rate(self) -> float:
        """Probability that a proposal holds exactly k cells (binomial pmf)."""
        j, m = self.bernoulli
        p, n, k = j / 2**m, self.grid_size**2 - 1, self.num_cells
        return math.comb(n, k) * p**k * (1 - p) ** (n - k)

    @property
    def slots_per_round(self) -> int:
        """J: flood-filled slots per round (dense maps are rarely valid, sparse ones almost always)."""
        density = self.num_cells / (self.grid_size**2 - 1)
        return 64 if density > 0.3 else 16 if density > 0.15 else 4

    @property
    def round_limit(self) -> int:
        """Rounds before giving up: each round finds a valid set with probability at least
        1 - exp(-J rate), so at `MIN_VALID_RATE` giving up has probability below e^-40."""
        if self.max_rounds is not None:
            return self.max_rounds
        return math.ceil(40 / (self.slots_per_round * MIN_VALID_RATE))

    @property
    def proposals_per_round(self) -> int:
        """R: raw proposals per round, about 4 J count-passing ones (the cheap filter drops some)."""
        return 8 * math.ceil(4 * self.slots_per_round / self.count_rate / 8)


# ---------------------------------------------------------------- bitboards


def rotate_cols(rows: jax.Array, shift: int, n: int) -> jax.Array:
    """Rotate every row by `shift` in {-1, 1} columns on the torus. `rows`: uint32[..., N]."""
    mask = jnp.uint32((1 << n) - 1)
    if shift == 1:
        return ((rows << 1) | (rows >> (n - 1))) & mask
    return ((rows >> 1) | (rows << (n - 1))) & mask


def neighbours(rows: jax.Array, n: int) -> jax.Array:
    """Cells with a 4-neighbour in `rows` (the cells themselves excluded), torus-wrapped."""
    return (
        rotate_cols(rows, 1, n)
        | rotate_cols(rows, -1, n)
        | jnp.roll(rows, 1, axis=-1)
        | jnp.roll(rows, -1, axis=-1)
    )


def board_to_grid(rows: jax.Array, n: int) -> jax.Array:
    """uint32[..., N] bitboard -> bool[..., N, N] occupancy."""
    return ((rows[..., :, None] >> jnp.arange(n, dtype=jnp.uint32)) & 1).astype(bool)


def grid_to_board(occupied: jax.Array) -> jax.Array:
    """bool[..., N, N] occupancy -> uint32[..., N] bitboard."""
    n = occupied.shape[-1]
    weights = jnp.left_shift(jnp.uint32(1), jnp.arange(n, dtype=jnp.uint32))
    return jnp.sum(occupied.astype(jnp.uint32) * weights, axis=-1, dtype=jnp.uint32)


def is_valid_board(rows: jax.Array, n: int) -> jax.Array:
    """The original's validity test on bitboards `uint32[..., N]` -> bool[...].

    Flood-fills the empty cells from (0, 0); the map is valid iff the filled cells and their
    neighbours cover the grid.
    """
    mask = jnp.uint32((1 << n) - 1)
    empty = ~rows & mask
    start = jnp.zeros_like(rows).at[..., 0].set(1)

    def grow(reach: jax.Array) -> jax.Array:
        reach = (reach | neighbours(reach, n)) & empty
        return (reach | neighbours(reach, n)) & empty

    def not_done(carry: tuple[jax.Array, jax.Array]) -> jax.Array:
        reach, previous = carry
        return jnp.any(reach != previous)

    reach, _ = jax.lax.while_loop(
        not_done, lambda carry: (grow(carry[0]), carry[0]), (grow(start), start)
    )
    return jnp.all((reach | neighbours(reach, n)) == mask, axis=-1)


# ---------------------------------------------------------------- exact sampling


def _propose(key: jax.Array, spec: MapSpec, num: int) -> jax.Array:
    """`num` boards, each non-start cell occupied with probability j / 2^m: uint32[num, N]."""
    j, m = spec.bernoulli
    n = spec.grid_size
    words = jax.random.bits(key, (m, num, n), jnp.uint32)
    rows = jnp.zeros((num, n), jnp.uint32)
    for bit in range(m):  # least significant bit of j first: P = 0.b1 b2 ... bm in binary
        if (j >> bit) & 1:
            rows = rows | words[bit]
        else:
            rows = rows & words[bit]
    rows = rows & jnp.uint32(spec.row_mask)
    return rows.at[:, 0].set(rows[:, 0] & ~jnp.uint32(1))


def _passes_cheap_filter(rows: jax.Array, spec: MapSpec) -> jax.Array:
    """k occupied cells and every cell has an empty 4-neighbour (necessary for validity)."""
    n, mask = spec.grid_size, jnp.uint32(spec.row_mask)
    count = jnp.sum(jax.lax.population_count(rows).astype(jnp.int32), axis=-1)
    covered = jnp.all(neighbours(~rows & mask, n) == mask, axis=-1)
    return (count == spec.num_cells) & covered


def sample_board(key: jax.Array, spec: MapSpec) -> jax.Array:
    """A uniform valid set of k cells, as a bitboard uint32[N] (jittable, vmappable).

    After `spec.round_limit` fruitless rounds: `spec.fallback` (and a failed `debug_check`).
    """
    num_raw, num_slots = spec.proposals_per_round, spec.slots_per_round

    def round_(carry: tuple[jax.Array, jax.Array, jax.Array, jax.Array]) -> tuple:
        key, rounds, _, board = carry
        key, key_round = jax.random.split(key)
        boards = _propose(key_round, spec, num_raw)
        passing = _passes_cheap_filter(boards, spec)
        (index,) = jnp.nonzero(passing, size=num_slots, fill_value=0)
        in_use = jnp.arange(num_slots) < jnp.sum(passing)
        valid = in_use & is_valid_board(boards[index], spec.grid_size)
        first = jnp.argmax(valid)
        found = valid[first]
        return key, rounds + 1, found, jnp.where(found, boards[index[first]], boards[index[0]])

    def searching(carry: tuple[jax.Array, jax.Array, jax.Array, jax.Array]) -> jax.Array:
        return ~carry[2] & (carry[1] < spec.round_limit)

    init = (key, jnp.asarray(0), jnp.asarray(False), jnp.zeros((spec.grid_size,), jnp.uint32))
    _, _, found, board = jax.lax.while_loop(searching, round_, init)
    sampler_check(
        found, f"no valid {spec.grid_size}x{spec.grid_size} map with {spec.num_cells} letter "
        f"cells in {spec.round_limit} sampling rounds; valid maps are too rare for this config"
    )
    if spec.fallback is not None:
        board = jnp.where(found, board, jnp.asarray(spec.fallback, jnp.uint32))
    return board


# ---------------------------------------------------------------- host-side rate estimate


def _valid_boards_np(rows: np.ndarray, n: int) -> np.ndarray:
    """numpy twin of `is_valid_board` for uint32[M, N] bitboards -> bool[M]."""
    mask = np.uint32((1 << n) - 1)

    def around(r: np.ndarray) -> np.ndarray:
        left = ((r << np.uint32(1)) | (r >> np.uint32(n - 1))) & mask
        right = ((r >> np.uint32(1)) | (r << np.uint32(n - 1))) & mask
        return left | right | np.roll(r, 1, axis=-1) | np.roll(r, -1, axis=-1)

    empty = ~rows & mask
    reach = np.zeros_like(rows)
    reach[:, 0] = 1
    while True:
        grown = (reach | around(reach)) & empty
        if np.array_equal(grown, reach):
            return np.all((reach | around(reach)) == mask, axis=-1)
        reach = grown


@functools.lru_cache(maxsize=None)
def valid_rate(
    grid_size: int, num_cells: int, max_samples: int = 32768, enough: int = 16
) -> tuple[int, int, tuple[int, ...] | None]:
    """Monte Carlo count of valid sets among uniform k-subsets of the non-start cells.

    Draws batches of 2048 until `enough` valid sets are seen or `max_samples` are drawn.

    Returns:
        `(valid, drawn, board)`: the counts, and the bitboard rows of the first valid set seen
        (None if none was).
    """
    n, free = grid_size, grid_size * grid_size - 1
    rng = np.random.default_rng(n * 4096 + num_cells)
    weights = np.left_shift(np.uint64(1), np.arange(n, dtype=np.uint64))
    valid, drawn, first = 0, 0, None
    while valid < enough and drawn < max_samples:
        cells = np.argpartition(rng.random((2048, free)), num_cells, axis=1)[:, :num_cells] + 1
        occupied = np.zeros((2048, n * n), bool)
        np.put_along_axis(occupied, cells, True, axis=1)
        rows = (occupied.reshape(2048, n, n) * weights).sum(axis=-1).astype(np.uint32)
        ok = _valid_boards_np(rows, n)
        if first is None and ok.any():
            first = tuple(int(r) for r in rows[np.argmax(ok)])
        valid, drawn = valid + int(ok.sum()), drawn + 2048
    return valid, drawn, first


def ordinal_grid(board: jax.Array, n: int) -> jax.Array:
    """int8[N, N]: the row-major ordinal of each occupied cell, -1 where empty."""
    occupied = board_to_grid(board, n)
    ordinal = jnp.cumsum(occupied.reshape(-1)).reshape(n, n) - 1
    return jnp.where(occupied, ordinal, -1).astype(jnp.int8)


def sample_letters(key: jax.Array, spec: MapSpec) -> jax.Array:
    """A uniform valid map: int8[N, N], the letter index of each cell, -1 where empty."""
    key_board, key_labels = jax.random.split(key)
    ordinal = ordinal_grid(sample_board(key_board, spec), spec.grid_size)
    slots = jax.random.permutation(key_labels, jnp.asarray(spec.slot_letters, jnp.int8))
    return jnp.where(ordinal >= 0, slots[jnp.maximum(ordinal, 0)], -1).astype(jnp.int8)


# ---------------------------------------------------------------- map bank (opt-in fast resets)


def sample_bank(key: jax.Array, spec: MapSpec, num_maps: int, chunk: int = 4096) -> jax.Array:
    """`num_maps` exactly sampled valid sets as ordinal grids int8[num_maps, N, N]."""
    num_chunks = -(-num_maps // chunk)
    size = min(chunk, num_maps)
    keys = jax.random.split(key, num_chunks * size).reshape(num_chunks, size)
    sample_chunk = jax.vmap(lambda k: ordinal_grid(sample_board(k, spec), spec.grid_size))
    bank = jax.lax.map(sample_chunk, keys)
    return bank.reshape(-1, spec.grid_size, spec.grid_size)[:num_maps]


def letters_from_bank(key: jax.Array, bank: jax.Array, spec: MapSpec) -> jax.Array:
    """A map from the bank: uniform entry, uniform symmetry fixing (0, 0), uniform labelling.

    Args:
        key: PRNG key.
        bank: int8[M, N, N] ordinal grids from `sample_bank`.
        spec: the map distribution the bank was drawn from.

    Returns:
        int8[N, N] letter indices, -1 where empty.
    """
    k = spec.num_cells
    key_entry, key_symmetry, key_labels = jax.random.split(key, 3)
    entry = jnp.asarray(bank)[jax.random.randint(key_entry, (), 0, bank.shape[0])]
    flips = jax.random.bernoulli(key_symmetry, 0.5, (3,))
    entry = jnp.where(flips[0], entry.T, entry)
    # r -> -r mod N (and c -> -c mod N) as static slices: row 0 stays, the rest reverses.
    entry = jnp.where(flips[1], jnp.concatenate([entry[:1], entry[:0:-1]], axis=0), entry)
    entry = jnp.where(flips[2], jnp.concatenate([entry[:, :1], entry[:, :0:-1]], axis=1), entry)
    ordinal = entry.astype(jnp.int32)
    # A uniform permutation as the ranks of i.i.d. keys (ties broken by index): no sort needed.
    u = jax.random.bits(key_labels, (k,), jnp.uint32)
    index = jnp.arange(k)
    before = (u[None, :] < u[:, None]) | (
        (u[None, :] == u[:, None]) & (index[None, :] < index[:, None])
    )
    rank = jnp.sum(before, axis=1)
    # The barrier keeps XLA from fusing (and so recomputing) the k x k ranking into every cell.
    slot_letters = jax.lax.optimization_barrier(jnp.asarray(spec.slot_letters, jnp.int8)[rank])
    return jnp.where(ordinal >= 0, slot_letters[jnp.maximum(ordinal, 0)], -1).astype(jnp.int8)
