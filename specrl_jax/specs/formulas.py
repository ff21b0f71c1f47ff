"""Host-side, seeded formula samplers and printers (Spot syntax).

Samplers take a `numpy.random.Generator` and the world's propositions and return formula text.
Every formula they emit is satisfiable under the "at most one proposition true" alphabet by
construction (the rule that guarantees it is stated per sampler); the tests confirm it with Spot.

Families:
* reach-only `F(g1 & F(g2 & ... F gL))` and reach-avoid `!A1 U (R1 & (!A2 U (R2 & ...)))`
  (SpecRLBench's samplers), and `cyclic_reach_avoid`, the reach-avoid rows of the paper's
  complexity table;
* LTL2Action's `Until_a_b_c_d` and `Eventually_a_b_c_d` families;
* `sequence_to_formula`: a training `ReachAvoidSequence` as a formula.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

import numpy as np

Goal = Sequence[str]


def _disjunction(props: Goal, wrap: bool) -> str:
    if not props:
        raise ValueError("a reach set must name at least one proposition")
    text = " | ".join(props)
    return f"({text})" if wrap and len(props) > 1 else text


def reach_only_formula(goals: Sequence[Goal]) -> str:
    """`F(g1 & F(g2 & ... F gL))`, each goal a disjunction, e.g. `F((a | b) & F(k | l))`."""
    if not goals:
        raise ValueError("need at least one goal")
    text = f"F({_disjunction(goals[-1], False)})" if len(goals[-1]) > 1 else f"F {goals[-1][0]}"
    for goal in reversed(goals[:-1]):
        text = f"F({_disjunction(goal, True)} & {text})"
    return text


def reach_avoid_formula(reaches: Sequence[Goal], avoids: Sequence[Goal]) -> str:
    """`!A1 U (R1 & (!A2 U (R2 & ...)))`, e.g. `!(a | b) U (c & (!(d | e) U f))`.

    An empty avoid set turns its `!A U` into `F`.
    """
    if len(reaches) != len(avoids) or not reaches:
        raise ValueError(f"need as many avoid sets as reach sets (>= 1), got {reaches}, {avoids}")

    def until(avoid: Goal, target: str, wrap_target: bool) -> str:
        if not avoid:
            return f"F({target})" if wrap_target else f"F {target}"
        negated = f"!{avoid[0]}" if len(avoid) == 1 else f"!({' | '.join(avoid)})"
        return f"{negated} U ({target})" if wrap_target else f"{negated} U {target}"

    last = _disjunction(reaches[-1], False)
    text = until(avoids[-1], last, len(reaches[-1]) > 1)
    for reach, avoid in zip(reversed(reaches[:-1]), reversed(avoids[:-1])):
        text = until(avoid, f"{_disjunction(reach, True)} & ({text})", True)
    return text


def _pick(rng: np.random.Generator, pool: Sequence[str], size: int) -> list[str]:
    """`size` distinct entries of `pool`, kept in the pool's order (stable printing)."""
    chosen = set(rng.choice(len(pool), size=size, replace=False).tolist())
    return [p for i, p in enumerate(pool) if i in chosen]


def _check_props(propositions: Sequence[str], needed: int, what: str) -> list[str]:
    props = list(propositions)
    if len(set(props)) != len(props):
        raise ValueError(f"propositions must be distinct, got {props}")
    if len(props) < needed:
        raise ValueError(f"{what} needs at least {needed} propositions, got {len(props)}")
    return props


def sample_reach_goals(
    rng: np.random.Generator, propositions: Sequence[str], seq_len: int, num_disj: int
) -> list[list[str]]:
    """`seq_len` goal sets of `num_disj` + 1 propositions, consecutive goals disjoint."""
    props = _check_props(propositions, 2 * (num_disj + 1), "the reach-only sampler")
    goals: list[list[str]] = []
    for _ in range(seq_len):
        pool = [p for p in props if not goals or p not in goals[-1]]
        goals.append(_pick(rng, pool, num_disj + 1))
    return goals


def sample_reach_only(
    rng: np.random.Generator, propositions: Sequence[str], seq_len: int, num_disj: int
) -> str:
    """Reach-only formula: `seq_len` goals in order, each a disjunction of `num_disj` + 1.

    Consecutive goals share no proposition (so every goal needs a visit of its own); any
    goal order is satisfiable, one proposition at a time.
    """
    return reach_only_formula(sample_reach_goals(rng, propositions, seq_len, num_disj))


def sample_reach_avoid(
    rng: np.random.Generator,
    propositions: Sequence[str],
    seq_len: int,
    num_reach: int,
    num_avoid: int,
) -> str:
    """Reach-avoid formula of `seq_len` pairs with |R_i| = `num_reach`, |A_i| = `num_avoid`.

    R_i is disjoint from R_{i-1}; A_i is disjoint from R_i and R_{i-1}. The second rule is what
    keeps the formula satisfiable with one proposition at a time: at the step where R_{i-1}
    holds, `!A_i` must hold too.
    """
    props = _check_props(propositions, 2 * num_reach + num_avoid, "the reach-avoid sampler")
    if num_reach < 1 or num_avoid < 0:
        raise ValueError(f"need num_reach >= 1 and num_avoid >= 0, got {num_reach}, {num_avoid}")
    reaches: list[list[str]] = []
    avoids: list[list[str]] = []
    previous: list[str] = []
    for _ in range(seq_len):
        reach = _pick(rng, [p for p in props if p not in previous], num_reach)
        avoids.append(_pick(rng, [p for p in props if p not in reach + previous], num_avoid))
        reaches.append(reach)
        previous = reach
    return reach_avoid_formula(reaches, avoids)


def cyclic_reach_avoid(
    propositions: Sequence[str], seq_len: int, num_avoid: int, start: int
) -> str:
    """The paper's complexity-table reach-avoid shape: propositions taken in cyclic order from
    `propositions[start]`, `num_avoid` avoided then one reached per pair.

    E.g. letters a..l, `seq_len=2, num_avoid=2, start=8` -> `!(i | j) U (k & (!(l | a) U b))`.
    Satisfiable with one proposition at a time whenever `num_avoid + 2 <= len(propositions)`:
    A_i is the `num_avoid` propositions after R_{i-1} in the cycle, so it never holds R_{i-1}
    or R_i, and R_i differs from R_{i-1}.
    """
    props = _check_props(propositions, num_avoid + 2, "the cyclic reach-avoid chain")
    if seq_len < 1 or num_avoid < 0 or not 0 <= start < len(props):
        raise ValueError(f"need seq_len >= 1, num_avoid >= 0 and 0 <= start < {len(props)}, got "
                         f"{seq_len}, {num_avoid}, {start}")
    cycle = [props[(start + i) % len(props)] for i in range(seq_len * (num_avoid + 1))]
    avoids = [cycle[i * (num_avoid + 1): i * (num_avoid + 1) + num_avoid] for i in range(seq_len)]
    reaches = [[cycle[i * (num_avoid + 1) + num_avoid]] for i in range(seq_len)]
    return reach_avoid_formula(reaches, avoids)


def sample_until(
    rng: np.random.Generator,
    propositions: Sequence[str],
    levels: tuple[int, int] = (1, 2),
    conjunctions: tuple[int, int] = (1, 1),
) -> str:
    """LTL2Action `Until_*`: a conjunction of nested `!p U (q & (!r U s))` chains.

    All propositions of the formula are distinct (LTL2Action draws 2 * max levels * max
    conjunctions of them at once), so no reach proposition is ever avoided: satisfiable.
    """
    props = _check_props(propositions, 2 * levels[1] * conjunctions[1], "Until sampling")
    pool = [props[i] for i in rng.permutation(len(props))]
    chains = []
    for _ in range(rng.integers(conjunctions[0], conjunctions[1] + 1)):
        depth = int(rng.integers(levels[0], levels[1] + 1))
        avoid, reach = pool.pop(), pool.pop()
        chain = f"!{avoid} U {reach}"
        for _ in range(depth - 1):
            avoid, reach = pool.pop(), pool.pop()
            chain = f"!{avoid} U ({reach} & ({chain}))"
        chains.append(f"({chain})")
    return " & ".join(reversed(chains))


def sample_eventually(
    rng: np.random.Generator,
    propositions: Sequence[str],
    levels: tuple[int, int] = (1, 4),
    conjunctions: tuple[int, int] = (1, 3),
    disjunct_prob: float = 0.25,
) -> str:
    """LTL2Action `Eventually_*`: a conjunction of `F(x & F(y & ...))` sequences.

    Each element is one proposition, or with `disjunct_prob` a disjunction of two; consecutive
    elements share none. Reach-only, hence always satisfiable.
    """
    props = _check_props(propositions, 3, "Eventually sampling")
    sequences = []
    for _ in range(rng.integers(conjunctions[0], conjunctions[1] + 1)):
        goals: list[list[str]] = []
        for _ in range(rng.integers(levels[0], levels[1] + 1)):
            pool = [p for p in props if not goals or p not in goals[-1]]
            goals.append(_pick(rng, pool, 2 if rng.random() < disjunct_prob else 1))
        sequences.append(f"({reach_only_formula(goals)})")
    return " & ".join(reversed(sequences))


_LTL2ACTION = re.compile(r"^(Until|Eventually)_(\d+)_(\d+)_(\d+)_(\d+)$")


def ltl2action_sampler(name: str) -> Callable[[np.random.Generator, Sequence[str]], str]:
    """`"Until_1_2_1_1"` / `"Eventually_1_5_1_4"` -> `sampler(rng, propositions) -> formula`.

    The four numbers are (min levels, max levels, min conjunctions, max conjunctions).
    """
    match = _LTL2ACTION.match(name)
    if match is None:
        raise ValueError(
            f"unknown LTL2Action sampler {name!r}; expected 'Until_a_b_c_d' or 'Eventually_a_b_c_d'"
        )
    kind, *numbers = match.groups()
    lo_l, hi_l, lo_c, hi_c = map(int, numbers)
    if not (1 <= lo_l <= hi_l and 1 <= lo_c <= hi_c):
        raise ValueError(f"{name!r}: need 1 <= min <= max for levels and conjunctions")
    family = sample_until if kind == "Until" else sample_eventually
    return lambda rng, propositions: family(rng, propositions, (lo_l, hi_l), (lo_c, hi_c))


def sequence_to_formula(sequence, propositions: Sequence[str]) -> str:
    """A single (unbatched, host) `ReachAvoidSequence` as formula text.

    Plain pairs become a reach-avoid chain; a reach-stay task (epsilon pair with avoid K, then a
    stay pair that also avoids the empty assignment) becomes `!K U G p`, the persistence goal the
    finite stay approximates.

    Raises:
        ValueError: a shape this mapping does not cover (epsilon or repeats outside reach-stay).
    """
    reach = np.asarray(sequence.reach)
    avoid = np.asarray(sequence.avoid)
    length = int(sequence.length)
    epsilon = np.asarray(sequence.epsilon)[:length]
    names = np.asarray(list(propositions))

    def props(row: np.ndarray) -> list[str]:
        return names[row].tolist()

    if epsilon.any():
        stay = props(reach[1])
        if length != 2 or not epsilon[0] or epsilon[1] or len(stay) != 1:
            raise ValueError("epsilon pairs are only mapped in reach-stay form (eps, stay p)")
        first = props(avoid[0])
        if not first:
            return f"F G {stay[0]}"
        negated = f"!{first[0]}" if len(first) == 1 else f"!({' | '.join(first)})"
        return f"{negated} U G {stay[0]}"
    if int(sequence.repeat_last) or np.asarray(sequence.avoid_empty)[:length].any():
        raise ValueError("repeats and empty-assignment avoids are only mapped for reach-stay")
    return reach_avoid_formula(
        [props(r) for r in reach[:length]], [props(a) for a in avoid[:length]]
    )
