"""The paper's evaluation formulas with the alphabets of their worlds."""

import os

import pytest
import yaml

from specrl_jax.automata import all_subsets, product, zero_or_one

REPO = os.path.join(os.path.dirname(__file__), "..", "..")
COLORS = ("blue", "green", "magenta", "yellow")


def _flatten(node):
    if isinstance(node, list):
        return list(node)
    return [f for value in node.values() for f in _flatten(value)]


def _paper_data():
    for path in (os.path.join(REPO, "specrl_jax", "specs", "data", "paper_specs.yaml"),
                 os.path.join(REPO, "..", "shared", "reference", "paper_specs.yaml")):
        if os.path.exists(path):
            with open(path) as f:
                return yaml.safe_load(f)
    pytest.skip("paper_specs.yaml not found (neither in specs/data nor ../shared/reference)")


def paper_groups():
    """{group: (formulas, propositions, alphabet)} for every table of the paper's appendix."""
    data = _paper_data()
    letters = tuple("abcdefghijkl")
    arm = tuple(f"arm_{c}" for c in COLORS) + tuple(f"grippers_{c}" for c in COLORS)
    agents = tuple(f"{c}_{i}" for i in range(2) for c in COLORS)
    alphabets = {
        "letter": (letters, zero_or_one(12)),
        "letter_complexity": (letters, zero_or_one(12)),
        "zone": (COLORS, zero_or_one(4)),
        "arm_grippers": (COLORS, zero_or_one(4)),
        "arm_grippers_arm": (arm, all_subsets(8)),
        "multi_agent_zone": (agents, product(zero_or_one(4), zero_or_one(4))),
    }
    return {g: (_flatten(data[g]), *alphabets[g]) for g in alphabets}


def paper_finite_formulas():
    """The formulas listed under a `finite` key or in the reach-only / reach-avoid tables."""
    data = _paper_data()
    finite = set(_flatten(data["letter_complexity"]))
    for tables in data.values():
        if isinstance(tables, dict) and "finite" in tables:
            finite |= set(_flatten(tables["finite"]))
    return finite
