"""Formulas that used to take long: deep nesting translates fast, oversized automata fail fast."""

import time

import pytest
import spot

from specrl_jax.automata import translate

LETTERS = tuple("abcdefghijkl")


def _nested_until(depth: int) -> str:
    formula = "a"
    for i in range(depth):
        formula = f"{LETTERS[(i + 1) % 12]} U ({formula})"
    return formula


def test_thirty_deep_nested_until_translates_in_well_under_a_second():
    # used to spend 17 s (2-core CPU) in Spot's automata-based implication checks
    text = _nested_until(30)
    assert translate.temporal_depth(spot.formula(text)) == 30
    start = time.perf_counter()
    automaton = translate.translate(text, LETTERS, translate.zero_or_one(12))
    assert time.perf_counter() - start < 3.0
    assert automaton.num_states == 30 and automaton.is_finite
    # same language as the fully simplified translation at a depth where that one is quick
    shallow = _nested_until(8)
    assert translate.temporal_depth(spot.formula(shallow)) <= translate.DEEP_NESTING
    # symbol i + 1 is letter i: `a` now satisfies every nesting, nothing now violates it, and
    # the outermost letter keeps it open
    for aut, outer in ((automaton, 30 % 12), (translate.translate(shallow, LETTERS,
                                                                  translate.zero_or_one(12)), 8)):
        assert aut.success[aut.delta[aut.init, 1]]
        assert aut.violation[aut.delta[aut.init, 0]]
        opened = aut.delta[aut.init, outer + 1]
        assert not aut.success[opened] and not aut.violation[opened]


def test_automaton_over_the_state_cap_fails_fast():
    # 2,048 states: used to fail after 9.5 s of table building and graph searches
    text = " & ".join(f"F {c}" for c in LETTERS[:11])
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"needs about 2048 automaton states.*at most 1024"):
        translate.translate(text, LETTERS, translate.zero_or_one(12))
    assert time.perf_counter() - start < 3.0
