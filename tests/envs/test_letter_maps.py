"""LetterWorld map sampling: validity rule, exactness of the distribution, the map bank."""

import itertools
import random
from collections import Counter

import jax
import numpy as np
import pytest
from scipy import stats

from specrl_jax.envs import letter_maps
from specrl_jax.envs.letter import LetterConfig

SPEC = LetterConfig().map_spec  # 7x7, 12 letters x 2


def reference_is_valid(occupied: set, n: int) -> bool:
    """The original's search: from (0, 0) over 4-neighbours, letter cells visited, not expanded."""
    seen, stack = {(0, 0)}, [(0, 0)]
    while stack:
        i, j = stack.pop()
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            cell = ((i + di) % n, (j + dj) % n)
            if cell not in seen:
                seen.add(cell)
                if cell not in occupied:
                    stack.append(cell)
    return len(seen) == n * n


def reference_sample(rng: random.Random, n: int, slots: list[int]) -> np.ndarray:
    """The original's rejection sampler: shuffle the non-start cells, letter k on cell k."""
    cells = [(i, j) for i in range(n) for j in range(n) if (i, j) != (0, 0)]
    while True:
        rng.shuffle(cells)
        placed = dict(zip(cells, slots))
        if reference_is_valid(set(placed), n):
            grid = -np.ones((n, n), np.int64)
            for (i, j), letter in placed.items():
                grid[i, j] = letter
            return grid


def sample_maps(spec: letter_maps.MapSpec, num: int, seed: int) -> np.ndarray:
    keys = jax.random.split(jax.random.key(seed), num)
    return np.asarray(jax.jit(jax.vmap(lambda k: letter_maps.sample_letters(k, spec)))(keys))


@pytest.fixture(scope="module")
def maps_7x7() -> np.ndarray:
    return sample_maps(SPEC, 3000, seed=0)


def test_bitboard_validity_matches_reference_search():
    boards = np.asarray(letter_maps._propose(jax.random.key(1), SPEC, 2500))
    grids = np.asarray(letter_maps.board_to_grid(boards, 7))
    valid = np.asarray(jax.jit(letter_maps.is_valid_board, static_argnums=1)(boards, 7))
    cheap = np.asarray(letter_maps._passes_cheap_filter(boards, SPEC))
    expected = np.array([reference_is_valid({tuple(c) for c in np.argwhere(g)}, 7) for g in grids])
    np.testing.assert_array_equal(valid, expected)
    assert expected.sum() > 20 and (~expected).sum() > 20
    exact_count = grids.sum(axis=(1, 2)) == 24
    assert not np.any(exact_count & expected & ~cheap)  # the cheap filter is necessary
    np.testing.assert_array_equal(np.asarray(letter_maps.grid_to_board(grids)), boards)


def test_sampled_maps_are_valid_with_exact_counts(maps_7x7):
    assert maps_7x7.dtype == np.int8 and maps_7x7.shape == (3000, 7, 7)
    assert np.all(maps_7x7[:, 0, 0] == -1)
    for grid in maps_7x7[:300]:
        assert reference_is_valid({tuple(c) for c in np.argwhere(grid >= 0)}, 7)
        np.testing.assert_array_equal(np.bincount(grid[grid >= 0], minlength=12), [2] * 12)
    assert len({g.tobytes() for g in maps_7x7}) == len(maps_7x7)


def test_exact_uniformity_by_enumeration_on_a_small_torus():
    """3x3 torus, letters a,a,b,b: every valid labelled map is equally likely (chi-square)."""
    spec = LetterConfig(grid_size=3, letters=("a", "b"), counts=2).map_spec
    cells = [(i, j) for i in range(3) for j in range(3) if (i, j) != (0, 0)]
    support = []
    for chosen in itertools.combinations(cells, 4):
        if reference_is_valid(set(chosen), 3):
            for labels in set(itertools.permutations([0, 0, 1, 1])):
                grid = -np.ones((3, 3), np.int8)
                for cell, letter in zip(chosen, labels):
                    grid[cell] = letter
                support.append(grid.tobytes())
    maps = sample_maps(spec, 6000, seed=2)
    counts = Counter(g.tobytes() for g in maps)
    assert set(counts) <= set(support)
    observed = np.array([counts.get(m, 0) for m in support])
    assert stats.chisquare(observed).pvalue > 1e-3


def map_statistics(maps: np.ndarray) -> dict[str, np.ndarray]:
    """Per map: letter cells next to the start, adjacent letter-letter pairs, torus distance a-a."""
    occupied = maps >= 0
    pairs = (occupied & np.roll(occupied, 1, axis=1)).sum((1, 2)) + (
        occupied & np.roll(occupied, 1, axis=2)
    ).sum((1, 2))
    near_start = occupied[:, 1, 0] + occupied[:, -1, 0] + occupied[:, 0, 1] + occupied[:, 0, -1]
    statistics = {"near_start": near_start, "pairs": pairs}
    if np.all((maps == 0).sum((1, 2)) == 2):
        a_cells = np.array([np.argwhere(m == 0) for m in maps])
        d = np.abs(a_cells[:, 0] - a_cells[:, 1])
        statistics["a_distance"] = np.minimum(d, 7 - d).sum(axis=1)
    return statistics


def two_sample_pvalue(x: np.ndarray, y: np.ndarray, min_expected: int = 10) -> float:
    """Chi-square test of homogeneity on the values of x and y (sparse values pooled)."""
    values = np.union1d(x, y)
    table = np.array([[np.sum(x == v) for v in values], [np.sum(y == v) for v in values]])
    keep = table.sum(0) >= min_expected
    table = np.concatenate([table[:, keep], table[:, ~keep].sum(1, keepdims=True)], axis=1)
    table = table[:, table.sum(0) > 0]
    return stats.chi2_contingency(table).pvalue


def test_distribution_matches_the_original_rejection_sampler(maps_7x7):
    rng = random.Random(3)
    reference = np.stack([reference_sample(rng, 7, list(SPEC.slot_letters)) for _ in range(2000)])
    ours = maps_7x7
    # Per-cell occupancy over the 48 non-start cells.
    table = np.stack([(ours >= 0).sum(0).ravel()[1:], (reference >= 0).sum(0).ravel()[1:]])
    assert stats.chi2_contingency(table).pvalue > 1e-3
    for name, ours_stat in map_statistics(ours).items():
        pvalue = two_sample_pvalue(ours_stat, map_statistics(reference)[name])
        assert pvalue > 1e-3, name
    # The test has power: maps that only pass the cheap filter (no connectivity) are told apart.
    cheap_only = []
    while len(cheap_only) < 2000:
        boards = letter_maps._propose(jax.random.key(len(cheap_only)), SPEC, 4000)
        keep = np.asarray(letter_maps._passes_cheap_filter(boards, SPEC))
        cheap_only.extend(np.asarray(letter_maps.board_to_grid(boards, 7))[keep])
    cheap_pairs = map_statistics(np.where(np.stack(cheap_only[:2000]), 1, -1))["pairs"]
    assert two_sample_pvalue(cheap_pairs, map_statistics(reference)["pairs"]) < 1e-6


def test_bank_draws_are_valid_symmetric_and_freshly_labelled():
    bank = np.asarray(letter_maps.sample_bank(jax.random.key(4), SPEC, 8, chunk=4))
    assert bank.shape == (8, 7, 7) and bank.dtype == np.int8
    for ordinal in bank:
        np.testing.assert_array_equal(np.sort(ordinal[ordinal >= 0]), np.arange(24))
    keys = jax.random.split(jax.random.key(5), 2000)
    draws = np.asarray(
        jax.jit(jax.vmap(lambda k: letter_maps.letters_from_bank(k, bank[:1], SPEC)))(keys)
    )
    geometries = {(d >= 0).tobytes() for d in draws}
    labellings = {d.tobytes() for d in draws}
    r, c = np.meshgrid(np.arange(7), np.arange(7), indexing="ij")
    base = bank[0] >= 0
    orbit = set()
    for t, fr, fc in itertools.product([False, True], repeat=3):
        rr, cc = (c, r) if t else (r, c)
        rr, cc = (-rr) % 7 if fr else rr, (-cc) % 7 if fc else cc
        orbit.add(base[rr, cc].tobytes())
    assert geometries == orbit  # every symmetry of the torus fixing (0, 0) appears, nothing else
    assert len(labellings) == len(draws)
    for grid in draws[:100]:
        assert grid[0, 0] == -1
        np.testing.assert_array_equal(np.bincount(grid[grid >= 0], minlength=12), [2] * 12)
        assert reference_is_valid({tuple(x) for x in np.argwhere(grid >= 0)}, 7)
