"""Spot checks of formulas against an environment's propositions and alphabet.

A formula is satisfiable in a world when some infinite word over the world's alphabet (the
proposition assignments it can produce) satisfies it. We decide it as the emptiness of
`formula & G(alphabet constraint)` with Spot.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from typing import Literal

import spot

from specrl_jax.automata.translate import parse_formula

Alphabet = Literal["zero_or_one", "per_agent_zero_or_one", "all"]
ALPHABETS = ("zero_or_one", "per_agent_zero_or_one", "all")
_AGENT_SUFFIX = re.compile(r"^(.+)_(\d+)$")


def parse(formula: str, propositions: Sequence[str]) -> spot.formula:
    """Parse `formula` with Spot and check it names only `propositions`.

    Raises:
        ValueError: the text does not parse, or it uses a proposition the world lacks.
    """
    return parse_formula(formula, propositions)


def alphabet_constraint(propositions: Sequence[str], alphabet: Alphabet = "zero_or_one") -> str:
    """A Boolean formula (Spot syntax) true exactly on the assignments of the alphabet.

    Args:
        propositions: the world's proposition names.
        alphabet: "zero_or_one" (at most one proposition true: zones, letters, arm),
            "per_agent_zero_or_one" (at most one per agent, propositions named `<name>_<agent>`),
            or "all" (every subset: overlapping regions).
    """
    if alphabet == "all":
        return "1"
    if alphabet == "zero_or_one":
        groups = [list(propositions)]
    elif alphabet == "per_agent_zero_or_one":
        by_agent: dict[str, list[str]] = {}
        for p in propositions:
            match = _AGENT_SUFFIX.match(p)
            if match is None:
                raise ValueError(f"per-agent proposition {p!r} lacks an '_<agent>' suffix")
            by_agent.setdefault(match.group(2), []).append(p)
        groups = list(by_agent.values())
    else:
        raise ValueError(f"unknown alphabet {alphabet!r}; known: {', '.join(ALPHABETS)}")
    clauses = [f"!({a} & {b})" for g in groups for a, b in itertools.combinations(g, 2)]
    return " & ".join(clauses) if clauses else "1"


def is_satisfiable(
    formula: str, propositions: Sequence[str], alphabet: Alphabet = "zero_or_one"
) -> bool:
    """Whether some word over the alphabet of `propositions` satisfies `formula` (Spot).

    Raises:
        ValueError: the formula does not parse or names unknown propositions.
    """
    parse(formula, propositions)
    constrained = spot.formula(f"({formula}) & G({alphabet_constraint(propositions, alphabet)})")
    return not spot.translate(constrained, "low", "any").is_empty()
