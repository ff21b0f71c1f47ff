"""Host formula samplers: satisfiable (Spot), deterministic, and shaped as asked."""

import itertools

import numpy as np
import pytest
import spot
from spec_spot_helpers import accepts, reach_avoid_chain, reach_only_chain

from specrl_jax import specs
from specrl_jax.specs.suites import COLOURS, LETTERS


def test_printers_match_the_papers_rows():
    assert specs.reach_only_formula([["a", "b"], ["k", "l"]]) == "F((a | b) & F(k | l))"
    assert specs.reach_only_formula([["a"], ["b"], ["c"], ["d"]]) == "F(a & F(b & F(c & F d)))"
    assert (
        specs.reach_avoid_formula([["c"], ["f"]], [["a", "b"], ["d", "e"]])
        == "!(a | b) U (c & (!(d | e) U f))"
    )
    assert specs.reach_avoid_formula([["b"], ["d"]], [["a"], ["c"]]) == "!a U (b & (!c U d))"
    assert specs.reach_avoid_formula([["b", "c"]], [[]]) == "F(b | c)"


def test_satisfiability_checker_knows_the_alphabet():
    # SpecRLBench's failure mode: the next avoid set contains the current reach.
    unsat = "!b U (a & (!a U c))"
    assert not specs.is_satisfiable(unsat, LETTERS)
    assert specs.is_satisfiable(unsat, LETTERS, alphabet="all")
    assert not specs.is_satisfiable("F(blue & green)", COLOURS)
    assert specs.is_satisfiable(
        "F(blue_0 & green_1)", ("blue_0", "green_1"), "per_agent_zero_or_one"
    )
    with pytest.raises(ValueError, match="does not have"):
        specs.is_satisfiable("F x", LETTERS)
    with pytest.raises(ValueError, match="cannot parse"):
        specs.is_satisfiable("F (a", LETTERS)


@pytest.mark.parametrize("props", [LETTERS, COLOURS], ids=["letter", "zone"])
def test_reach_avoid_samples_are_satisfiable_and_well_formed(props):
    rng = np.random.default_rng(0)
    settings = [(n, r, a) for n in (1, 2, 3, 5) for r in (1, 2) for a in (0, 1, 2)]
    settings = [(n, r, a) for n, r, a in settings if 2 * r + a <= len(props)]
    for seq_len, num_reach, num_avoid in settings:
        for _ in range(8):
            text = specs.sample_reach_avoid(rng, props, seq_len, num_reach, num_avoid)
            assert specs.is_satisfiable(text, props), text
            pairs = reach_avoid_chain(text)
            assert len(pairs) == seq_len
            previous = frozenset()
            for reach, avoid in pairs:
                assert len(reach) == num_reach and len(avoid) == num_avoid
                assert not reach & avoid and not previous & avoid and not previous & reach
                previous = reach
            # The one-proposition-per-step walk through the reach sets is accepted.
            walk = [min(reach) for reach, _ in pairs]
            assert accepts(text, walk, props)
            # Entering the first avoid set first is rejected.
            if num_avoid:
                assert not accepts(text, [min(pairs[0][1]), *walk], props)


@pytest.mark.parametrize("props", [LETTERS, COLOURS], ids=["letter", "zone"])
def test_reach_only_samples_are_satisfiable_and_well_formed(props):
    rng = np.random.default_rng(1)
    for seq_len in (1, 2, 4, 7):
        for num_disj in range(len(props) // 2):
            text = specs.sample_reach_only(rng, props, seq_len, num_disj)
            assert specs.is_satisfiable(text, props)
            goals = reach_only_chain(text)
            assert len(goals) == seq_len
            assert all(len(g) == num_disj + 1 for g in goals)
            assert all(not a & b for a, b in itertools.pairwise(goals))


def test_samplers_are_deterministic_given_the_seed():
    def draw(seed):
        rng = np.random.default_rng(seed)
        return [specs.sample_reach_avoid(rng, LETTERS, 4, 1, 2) for _ in range(5)] + [
            specs.sample_reach_only(rng, LETTERS, 3, 1),
            specs.ltl2action_sampler("Eventually_1_5_1_4")(rng, LETTERS),
        ]

    assert draw(7) == draw(7)
    assert draw(7) != draw(8)


def test_sampler_rejects_too_few_propositions():
    with pytest.raises(ValueError, match="needs at least"):
        specs.sample_reach_avoid(np.random.default_rng(0), COLOURS, 2, 2, 1)
    with pytest.raises(ValueError, match="Until_a_b_c_d"):
        specs.ltl2action_sampler("Until_1_2")


def _until_chains(f: spot.formula) -> list[list[tuple[str, str]]]:
    """Conjunction of `!p U (q & (!r U s))` chains -> [[(avoid, reach), ...], ...]."""
    parts = list(f) if f.kind() == spot.op_And else [f]
    chains = []
    for part in parts:
        chain = []
        while part.kind() == spot.op_U:
            avoid = part[0][0].ap_name()
            right = part[1]
            if right.kind() == spot.op_ap:
                chain.append((avoid, right.ap_name()))
                break
            (reach,) = [c.ap_name() for c in right if c.kind() == spot.op_ap]
            (part,) = [c for c in right if c.kind() != spot.op_ap]
            chain.append((avoid, reach))
        chains.append(chain)
    return chains


@pytest.mark.parametrize(
    "name, props, levels, conjuncts",
    [("Until_1_2_1_1", COLOURS, (1, 2), (1, 1)), ("Until_1_3_1_2", LETTERS, (1, 3), (1, 2))],
)
def test_ltl2action_until_family(name, props, levels, conjuncts):
    sampler = specs.ltl2action_sampler(name)
    rng = np.random.default_rng(2)
    seen_levels, seen_conj = set(), set()
    for _ in range(150):
        text = sampler(rng, props)
        assert specs.is_satisfiable(text, props), text
        chains = _until_chains(spot.formula(text))
        used = [p for chain in chains for pair in chain for p in pair]
        assert len(used) == len(set(used)), text
        seen_conj.add(len(chains))
        seen_levels.update(len(c) for c in chains)
    assert seen_levels == set(range(levels[0], levels[1] + 1))
    assert seen_conj == set(range(conjuncts[0], conjuncts[1] + 1))


def test_ltl2action_eventually_family():
    sampler = specs.ltl2action_sampler("Eventually_1_5_1_4")
    rng = np.random.default_rng(3)
    sizes, lengths, conj = [], set(), set()
    for _ in range(100):
        text = sampler(rng, LETTERS)
        assert specs.is_satisfiable(text, LETTERS), text
        f = spot.formula(text)
        parts = list(f) if f.kind() == spot.op_And else [f]
        conj.add(len(parts))
        for part in parts:
            goals = reach_only_chain(str(part))
            lengths.add(len(goals))
            sizes += [len(g) for g in goals]
            assert all(not a & b for a, b in itertools.pairwise(goals))
    assert lengths == {1, 2, 3, 4, 5} and conj == {1, 2, 3, 4}
    assert set(sizes) == {1, 2}
    assert 0.15 < np.mean(np.array(sizes) == 2) < 0.35  # disjunction probability 0.25
