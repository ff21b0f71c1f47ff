"""Named evaluation suites: the paper's formula lists, its complexity grid, DeepLTL / GenZ lists.

    suite("zone/finite/ood")                           -> list of formula strings
    suite_info("letter/complexity/reach_avoid/seq4_disj1") -> SuiteInfo (formulas + metadata)
    list_suites()                                      -> every name

Names:
* `<family>/<finite|infinite>/<kind>` for the paper's tables, family one of `letter`, `zone`,
  `arm_grippers` (Arm level 0), `arm_grippers_arm` (Arm level 1), `multi_agent_zone`;
* `letter/complexity_paper/<reach_only|reach_avoid>/seq<L>_disj<D>`: the paper's example rows;
* `letter/complexity/<reach_only|reach_avoid>/seq<L>_disj<D>`, L in 2..10, D in 0..3: the grid,
  `COMPLEXITY_SIZE` formulas per cell drawn from `COMPLEXITY_SEED`. Reach-only: L goals of D+1
  propositions each, consecutive goals disjoint. Reach-avoid: L pairs with one reach letter and
  D+1 avoided ones, the letters taken in cyclic alphabetical order from a drawn start letter,
  as every reach-avoid row of the paper's table is (`seq2_disj1` from i =
  `!(i | j) U (k & (!(l | a) U b))`);
* `<deepltl|genz>/<letter|zone>/<finite|infinite>`: the methods' own test-task lists.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import hashlib
from importlib import resources
from typing import Literal

import numpy as np
import yaml

from specrl_jax.families import INFINITE_HORIZON_FACTOR
from specrl_jax.specs import formulas
from specrl_jax.specs.satisfiable import Alphabet

COLOURS = ("blue", "green", "magenta", "yellow")
LETTERS = tuple("abcdefghijkl")
COMPLEXITY_SEED = 20261122
COMPLEXITY_SIZE = 10
COMPLEXITY_SEQ_LENS = tuple(range(2, 11))
COMPLEXITY_DISJ = (0, 1, 2, 3)
COMPLEXITY_KINDS = ("reach_only", "reach_avoid")
#: how an infinite suite's episodes are scored, part of its version: an epsilon jump whose run
#: dies while the formula is still open falls back to the run that never jumped, not a violation
#: (`tasks.sources.fall_back_run`)
INFINITE_SCORING = "violation when the formula is violated; a wrong epsilon jump falls back"




@dataclasses.dataclass(frozen=True)
class SuiteInfo:
    """A named suite and what it needs from a world.

    Attributes:
        name: the suite name.
        formulas: formula texts (Spot syntax).
        propositions: the world's propositions, in the env's order.
        horizon: "finite" (co-safe: done on success) or "infinite".
        env_family: "letter", "zone", "arm" or "multi_agent_zone".
        alphabet: the assignments the world produces (see `satisfiable.alphabet_constraint`).
        source: where the formulas come from.
    """

    name: str
    formulas: tuple[str, ...]
    propositions: tuple[str, ...]
    horizon: Literal["finite", "infinite"]
    env_family: str
    alphabet: Alphabet
    source: str

    @property
    def is_finite(self) -> bool:
        return self.horizon == "finite"

    @property
    def version(self) -> str:
        """A short hash of the suite's formulas, propositions and horizon, and for a suite whose
        automata take epsilon jumps of how its episodes are scored (`INFINITE_SCORING`): any
        change to what the suite asks gives it a new version (`suite_version`)."""
        scoring = (INFINITE_SCORING,) if self.may_jump else ()
        text = "\n".join((self.horizon, ",".join(self.propositions), *self.formulas, *scoring))
        return hashlib.sha256(text.encode()).hexdigest()[:10]

    @property
    def may_jump(self) -> bool:
        """Whether some spec's automaton has an epsilon edge (persistence), so that the
        suite's scores depend on `INFINITE_SCORING`; never for a finite (co-safe) suite, whose
        automata are deterministic, so no formula is translated for it."""
        return not self.is_finite and _may_jump(self.formulas, self.propositions)

    @property
    def horizon_factor(self) -> int:
        """Episode length in units of the world's finite horizon: 1 for finite suites,
        `INFINITE_HORIZON_FACTOR` for infinite ones (LetterWorld 750, Zone 10,000, Arm 2,000
        steps), so that an agent can complete many cycles."""
        return 1 if self.is_finite else INFINITE_HORIZON_FACTOR


@functools.cache
def _may_jump(formulas: tuple[str, ...], propositions: tuple[str, ...]) -> bool:
    """Whether some formula's automaton has an epsilon edge (no deterministic Buchi automaton:
    persistence), over every assignment of the propositions."""
    from specrl_jax.automata import translate

    table = translate.all_subsets(len(propositions))
    return any(bool((np.asarray(translate.translate(f, propositions, table).epsilon) >= 0).any())
               for f in formulas)


# paper family -> (env family, propositions, alphabet)
_PAPER_FAMILIES: dict[str, tuple[str, tuple[str, ...], Alphabet]] = {
    "letter": ("letter", LETTERS, "zero_or_one"),
    "zone": ("zone", COLOURS, "zero_or_one"),
    "arm_grippers": ("arm", COLOURS, "zero_or_one"),
    "arm_grippers_arm": (
        "arm",
        tuple(f"{part}_{c}" for part in ("arm", "grippers") for c in COLOURS),
        "zero_or_one",
    ),
    "multi_agent_zone": (
        "multi_agent_zone",
        tuple(f"{c}_{agent}" for agent in (0, 1) for c in COLOURS),
        "per_agent_zero_or_one",
    ),
}
_METHOD_ENVS: dict[str, tuple[tuple[str, ...], str]] = {
    "letter": (LETTERS, "letter"),
    "zone": (COLOURS, "zone"),
}
_PAPER_SOURCE = "SpecRLBench paper, appendix table of evaluation specifications"
_METHOD_SOURCE = {
    "deepltl": "DeepLTL evaluation scripts (test tasks)",
    "genz": "GenZ-LTL evaluation scripts (test tasks; letter list with its missing comma fixed)",
}


def _load(filename: str) -> dict:
    with resources.files("specrl_jax.specs").joinpath("data", filename).open() as f:
        return yaml.safe_load(f)


@functools.cache
def _static_suites() -> dict[str, SuiteInfo]:
    suites: dict[str, SuiteInfo] = {}
    paper = _load("paper_specs.yaml")
    for family, (env_family, props, alphabet) in _PAPER_FAMILIES.items():
        for horizon, kinds in paper[family].items():
            for kind, texts in kinds.items():
                name = f"{family}/{horizon}/{kind}"
                suites[name] = SuiteInfo(
                    name, tuple(texts), props, horizon, env_family, alphabet, _PAPER_SOURCE
                )
    for kind, cells in paper["letter_complexity"].items():
        for cell, texts in cells.items():
            name = f"letter/complexity_paper/{kind}/{cell}"
            source = "SpecRLBench paper, complexity table example rows"
            suites[name] = SuiteInfo(
                name, tuple(texts), LETTERS, "finite", "letter", "zero_or_one", source
            )
    for method, envs in _load("method_specs.yaml").items():
        for env, horizons in envs.items():
            props, env_family = _METHOD_ENVS[env]
            for horizon, texts in horizons.items():
                name = f"{method}/{env}/{horizon}"
                suites[name] = SuiteInfo(
                    name,
                    tuple(texts),
                    props,
                    horizon,
                    env_family,
                    "zero_or_one",
                    _METHOD_SOURCE[method],
                )
    return suites


def complexity_formulas(
    kind: str, seq_len: int, num_disj: int, size: int = COMPLEXITY_SIZE, seed: int = COMPLEXITY_SEED
) -> tuple[str, ...]:
    """`size` distinct LetterWorld formulas of one complexity-grid cell, fixed by `seed`.

    Reach-only: sampled goal chains. Reach-avoid: the cyclic chains of `size` distinct start
    letters (the paper's rows are those from a, e and i); their automata have at most 193
    states (seq10_disj0).

    Args:
        kind: "reach_only" or "reach_avoid".
        seq_len: number of goals (reach-only) or reach-avoid pairs.
        num_disj: disjunctions per goal (reach-only) or per avoid set (reach-avoid).
        size: formulas in the cell.
        seed: base seed; the cell's generator is seeded by (seed, kind, seq_len, num_disj).
    """
    if kind not in COMPLEXITY_KINDS:
        raise ValueError(f"kind must be one of {COMPLEXITY_KINDS}, got {kind!r}")
    rng = np.random.default_rng([seed, COMPLEXITY_KINDS.index(kind), seq_len, num_disj])
    if kind == "reach_avoid":
        if size > len(LETTERS):
            raise ValueError(f"a reach-avoid cell has {len(LETTERS)} formulas (one per start "
                             f"letter), asked for {size}")
        starts = rng.choice(len(LETTERS), size=size, replace=False).tolist()
        return tuple(formulas.cyclic_reach_avoid(LETTERS, seq_len, num_disj + 1, int(start))
                     for start in starts)
    found: dict[str, None] = {}
    for _ in range(100 * size):
        text = formulas.sample_reach_only(rng, LETTERS, seq_len, num_disj)
        found.setdefault(text)
        if len(found) == size:
            return tuple(found)
    raise ValueError(f"cell {kind}/seq{seq_len}_disj{num_disj} has fewer than {size} formulas")


@functools.cache
def _complexity_names() -> tuple[str, ...]:
    return tuple(
        f"letter/complexity/{kind}/seq{n}_disj{d}"
        for kind in COMPLEXITY_KINDS
        for n in COMPLEXITY_SEQ_LENS
        for d in COMPLEXITY_DISJ
    )


@functools.cache
def _complexity_suite(name: str) -> SuiteInfo:
    kind, cell = name.split("/")[2:]
    seq_len, num_disj = (int(x) for x in cell[3:].split("_disj"))
    source = f"generated: seed {COMPLEXITY_SEED}, {COMPLEXITY_SIZE} per cell"
    return SuiteInfo(
        name,
        complexity_formulas(kind, seq_len, num_disj),
        LETTERS,
        "finite",
        "letter",
        "zero_or_one",
        source,
    )


#: suites added at run time (`register_suite`): a user's own, or a test's
_REGISTERED: dict[str, SuiteInfo] = {}


def register_suite(name: str, formulas_: tuple[str, ...] | list[str], propositions: tuple[str, ...],
                   horizon: Literal["finite", "infinite"] = "finite", env_family: str = "",
                   alphabet: Alphabet = "zero_or_one", source: str = "registered") -> SuiteInfo:
    """Add a named suite of `formulas_` over `propositions` (e.g. for a world family of one's own).

    Raises:
        ValueError: the name is taken, or no formula is given.
    """
    if name in _static_suites() or name in _complexity_names() or name in _REGISTERED:
        raise ValueError(f"suite {name!r} already exists")
    if not formulas_:
        raise ValueError(f"suite {name!r} has no formula")
    info = SuiteInfo(name, tuple(formulas_), tuple(propositions), horizon, env_family, alphabet,
                     source)
    _REGISTERED[name] = info
    return info


def unregister_suite(name: str) -> None:
    """Remove a suite added by `register_suite`."""
    _REGISTERED.pop(name, None)


def list_suites(prefix: str = "") -> list[str]:
    """Every suite name (starting with `prefix`), sorted."""
    names = list(_static_suites()) + list(_complexity_names()) + list(_REGISTERED)
    return sorted(n for n in names if n.startswith(prefix))


def suite_info(name: str) -> SuiteInfo:
    """The named suite with its metadata.

    Raises:
        ValueError: unknown name (the message lists close matches and the known names).
    """
    if not isinstance(name, str):
        raise TypeError(f"suite name must be a string, got {type(name).__name__}")
    static = _static_suites()
    if name in static:
        return static[name]
    if name in _REGISTERED:
        return _REGISTERED[name]
    if name in _complexity_names():
        return _complexity_suite(name)
    known = list_suites()
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    families = sorted({n.rsplit("/", 1)[0] + "/..." for n in known if "complexity/" in n})
    shown = [n for n in known if "complexity/" not in n] + families
    raise ValueError(f"unknown suite {name!r}.{hint} Known suites: {', '.join(shown)}")


def suite_version(name: str) -> str:
    """The named suite's version: a short hash of its formulas, propositions and horizon."""
    return suite_info(name).version


def suite(name: str) -> list[str]:
    """The formulas of the named suite (a fresh list)."""
    return list(suite_info(name).formulas)
