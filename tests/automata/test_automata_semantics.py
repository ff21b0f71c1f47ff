"""Compiled specs agree with Spot's own automata on random lasso words (paper and random formulas)."""

import numpy as np
import pytest
import spot
from automata_lasso import check_formulas
from automata_paper import paper_finite_formulas, paper_groups

from specrl_jax.automata import all_subsets, compile_spec, zero_or_one


@pytest.mark.parametrize("group", ["letter", "letter_complexity", "zone", "arm_grippers_arm",
                                   "multi_agent_zone"])
def test_paper_formulas_match_spot(group):
    formulas, props, alphabet = paper_groups()[group]
    compiled, unsat = check_formulas(formulas, props, alphabet, np.random.default_rng(0))
    assert compiled == len(formulas) and unsat == 0


def test_paper_horizons_match_the_tables():
    finite = paper_finite_formulas()
    for formulas, props, alphabet in paper_groups().values():
        for text in formulas:
            spec = compile_spec(text, props, alphabet)
            assert bool(spec.is_finite) == (text in finite), text
            assert not bool(spec.success[spec.init]) and not bool(spec.violation[spec.init])


def test_arm_grippers_lists_the_zone_formulas():
    groups = paper_groups()
    assert groups["arm_grippers"][0] == groups["zone"][0]


def _random_formulas(aps, count, seed):
    gen = spot.randltl(list(aps), count, seed=seed, tree_size=(6, 18))
    return [str(f) for f in gen]


@pytest.mark.parametrize(
    "props, alphabet, seed",
    [(("a", "b", "c", "d"), zero_or_one(4), 1), (("a", "b", "c"), all_subsets(3), 2)],
    ids=["zero_or_one", "all_subsets"],
)
def test_random_formulas_match_spot(props, alphabet, seed):
    formulas = _random_formulas(("a", "b", "c"), 150, seed)
    compiled, unsat = check_formulas(formulas, props, alphabet, np.random.default_rng(seed), 4)
    assert compiled + unsat == len(formulas) and compiled > 100


FG_FORMULAS = [
    "FG a", "FG a & F(b & F c)", "FG a | GF b", "FG (a | b)", "FG a | FG b", "F(a & X G b)",
    "FG a & G !c", "GF a -> FG b", "F G (a | b) & G F b & G !(c | d)",
]


def test_epsilon_timing_accepts_iff_word_satisfies():
    props = ("a", "b", "c", "d")
    for text in FG_FORMULAS:
        spec = compile_spec(text, props, zero_or_one(4))
        assert (np.asarray(spec.epsilon) >= 0).any(), f"{text!r} should need epsilon moves"
    compiled, _ = check_formulas(FG_FORMULAS, props, zero_or_one(4), np.random.default_rng(3), 12)
    assert compiled == len(FG_FORMULAS)
