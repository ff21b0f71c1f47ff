"""Spot-side readers for the tests: decompose chain formulas, build single-letter words."""

from __future__ import annotations

from collections.abc import Sequence

import spot


def ap_set(f: spot.formula) -> frozenset[str]:
    """The propositions of a disjunction of propositions (or a single one)."""
    if f.kind() == spot.op_ap:
        return frozenset([f.ap_name()])
    assert f.kind() == spot.op_Or, f"not a disjunction of propositions: {f}"
    return frozenset(c.ap_name() for c in f)


def reach_only_chain(text: str) -> list[frozenset[str]]:
    """`F(g1 & F(g2 & ... F gL))` -> [g1, ..., gL] read off Spot's syntax tree."""
    f = spot.formula(text)
    goals = []
    while True:
        assert f.kind() == spot.op_F, f"expected F, got {f}"
        body = f[0]
        if body.kind() != spot.op_And:
            goals.append(ap_set(body))
            return goals
        (goal,) = [c for c in body if c.is_boolean()]
        (rest,) = [c for c in body if not c.is_boolean()]
        goals.append(ap_set(goal))
        f = rest


def reach_avoid_chain(text: str) -> list[tuple[frozenset[str], frozenset[str]]]:
    """`!A1 U (R1 & (!A2 U ...))` -> [(R1, A1), ...] read off Spot's syntax tree.

    `F(R & ...)` stands for an empty avoid set.
    """
    f = spot.formula(text)
    pairs = []
    while True:
        if f.kind() == spot.op_F:
            avoid, right = frozenset(), f[0]
        else:
            assert f.kind() == spot.op_U, f"expected U or F, got {f}"
            left, right = f[0], f[1]
            assert left.kind() == spot.op_Not, f"expected a negated avoid set, got {left}"
            avoid = ap_set(left[0])
        if right.kind() != spot.op_And:
            pairs.append((ap_set(right), avoid))
            return pairs
        (reach,) = [c for c in right if c.is_boolean()]
        (rest,) = [c for c in right if not c.is_boolean()]
        pairs.append((ap_set(reach), avoid))
        f = rest


def accepts(text: str, letters: Sequence[str | None], propositions: Sequence[str]) -> bool:
    """Whether `text` accepts the word `letters` (one true proposition or None per step),
    followed by nothing true forever."""

    def cube(true: str | None) -> str:
        return " & ".join(p if p == true else f"!{p}" for p in propositions)

    word = "; ".join([cube(x) for x in letters] + [f"cycle{{{cube(None)}}}"])
    return spot.translate(text).intersects(spot.parse_word(word).as_automaton())
