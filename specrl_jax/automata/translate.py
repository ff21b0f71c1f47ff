"""LTL text -> Spot automaton -> dense host tables over a declared alphabet.

The alphabet is the set of proposition assignments the world can produce (`bool[A, P]`). The
formula is conjoined with `G allowed` (the alphabet projected on the formula's propositions),
so Spot simplifies and minimises over the restricted alphabet, and unsatisfiability is
relative to it. Then:

* if Spot finds a deterministic Buchi automaton (every co-safe formula, GF families), we use
  it as is: no epsilon transitions;
* otherwise Spot gives a deterministic min-even parity automaton, from which we build a
  limit-deterministic Buchi automaton: the parity automaton itself as the initial part, and for
  every even colour k a deterministic copy that keeps only colours >= k and accepts colour k;
  epsilon transitions jump into copy k at states of its accepting SCCs (docs/automata.md).

Bounded effort: formulas whose temporal operators nest deeper than `DEEP_NESTING` (deeper than
any suite formula, which reach 10) are simplified by Spot with syntactic implication rules only
(`tls-impl=1`), because its automata-based implication checks grow steeply with depth (a
30-deep nested until: 17 s instead of 0.05 s, the same 29-state automaton); the automaton is
exact either way. An automaton Spot returns with more than `FAIL_FAST_STATES` states fails at
once, before the tables and graph searches that take seconds at that size.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence

import numpy as np
import spot

import buddy  # isort: skip  (importable once spot has put its own directory on sys.path)

from specrl_jax.automata import graph

MAX_SYMBOLS = 4096
MAX_STATES = 1024
#: Spot automata above this many states fail before our tables are built: merging dead and
#: universal states removes few of Spot's (it trims and minimises), so these cannot fit MAX_STATES
FAIL_FAST_STATES = MAX_STATES + MAX_STATES // 4
#: temporal nesting depth past which Spot's simplifier uses syntactic implications only
DEEP_NESTING = 16

_TEMPORAL = (spot.op_U, spot.op_R, spot.op_W, spot.op_M, spot.op_F, spot.op_G, spot.op_X)


@dataclasses.dataclass(frozen=True)
class Automaton:
    """A complete automaton over the alphabet's rows, as numpy tables (host side).

    Attributes:
        delta: int32[S, A] successor per alphabet symbol.
        accepting: bool[S, A] the transition is Buchi-accepting.
        epsilon: int32[S, E] epsilon successors, -1 padded (E >= 1).
        success: bool[S] every continuation satisfies the formula.
        violation: bool[S] no continuation satisfies it (one sink state).
        init: initial state.
        is_finite: co-safe over the alphabet: every accepted word reaches a success state.
    """

    delta: np.ndarray
    accepting: np.ndarray
    epsilon: np.ndarray
    success: np.ndarray
    violation: np.ndarray
    init: int
    is_finite: bool

    @property
    def num_states(self) -> int:
        return self.delta.shape[0]


def parse_formula(text: str, propositions: Sequence[str]) -> spot.formula:
    """Parse Spot LTL text and check its propositions against the env's names."""
    if not isinstance(text, str):
        raise TypeError(f"formula must be a str in Spot's LTL syntax, got {type(text).__name__}")
    try:
        formula = spot.formula(text)
    except SyntaxError as err:
        raise ValueError(f"cannot parse LTL formula {text!r}:{err}") from None
    if not formula.is_ltl_formula():
        raise ValueError(f"{text!r} is not an LTL formula (PSL/SERE operators are not accepted)")
    unknown = sorted({str(ap) for ap in spot.atomic_prop_collect(formula)} - set(propositions))
    if unknown:
        raise ValueError(
            f"formula {text!r} uses propositions {unknown} that the env does not have; "
            f"known: {list(propositions)}"
        )
    return formula


def check_alphabet(alphabet: np.ndarray, propositions: Sequence[str]) -> np.ndarray:
    """Validate an alphabet `bool[A, P]` (distinct rows, P = number of propositions)."""
    arr = np.asarray(alphabet)
    num_props = len(propositions)
    if arr.ndim != 2 or arr.shape[1] != num_props:
        raise ValueError(
            f"alphabet must have shape [A, {num_props}] (one column per proposition "
            f"{list(propositions)}), got shape {arr.shape}"
        )
    if arr.dtype != bool:
        if not np.isin(arr, (0, 1)).all():
            raise ValueError(f"alphabet must be boolean (or 0/1), got dtype {arr.dtype}")
        arr = arr.astype(bool)
    if not 1 <= arr.shape[0] <= MAX_SYMBOLS:
        raise ValueError(f"alphabet must have 1..{MAX_SYMBOLS} rows, got {arr.shape[0]}")
    if len(np.unique(arr, axis=0)) != arr.shape[0]:
        raise ValueError("alphabet rows must be distinct assignments")
    return arr


def translate(text: str, propositions: Sequence[str], alphabet: np.ndarray) -> Automaton:
    """Translate an LTL formula into dense tables over `alphabet` (see module docstring).

    Raises:
        ValueError: syntax error, unknown proposition, bad alphabet, a formula unsatisfiable
            over the alphabet, or an automaton of more than MAX_STATES states.
    """
    formula = parse_formula(text, propositions)
    alphabet = check_alphabet(alphabet, propositions)
    aps = sorted(str(ap) for ap in spot.atomic_prop_collect(formula))
    proj = alphabet[:, [list(propositions).index(ap) for ap in aps]]
    minterms, inverse = np.unique(proj, axis=0, return_inverse=True)
    restricted = spot.formula.And([formula, spot.formula.G(_allowed(aps, minterms))])
    xargs = "tls-impl=1" if temporal_depth(formula) > DEEP_NESTING else None

    aut = _checked_size(spot.translate(restricted, "Buchi", "deterministic", xargs=xargs), text)
    if not spot.is_deterministic(aut):
        # a deterministic generalised-Buchi automaton degeneralises to a deterministic one
        generic = spot.translate(restricted, "generic", "deterministic", xargs=xargs)
        if spot.is_deterministic(generic) and generic.acc().is_generalized_buchi():
            aut = spot.degeneralize_tba(generic)
    if aut.is_empty():
        raise ValueError(
            f"formula {text!r} is unsatisfiable over the alphabet: no infinite word of its "
            f"{alphabet.shape[0]} assignments over {list(propositions)} satisfies it"
        )
    if spot.is_deterministic(aut):
        tables = _dba_tables(aut, aps, minterms)
    else:
        dpa = _checked_size(
            spot.translate(restricted, "parity min even", "deterministic", "colored", xargs=xargs),
            text,
        )
        tables = _ldba_tables(dpa, aps, minterms)
    delta, accepting, epsilon, init, universal = tables
    return _finalize(delta[:, inverse.reshape(-1)], accepting[:, inverse.reshape(-1)],
                     epsilon, init, universal, text)


def temporal_depth(formula: spot.formula) -> int:
    """How deeply temporal operators (U, R, W, M, F, G, X) nest in `formula`."""
    inner = max((temporal_depth(child) for child in formula), default=0)
    return inner + (formula.kind() in _TEMPORAL)


def _checked_size(aut: spot.twa_graph, text: str) -> spot.twa_graph:
    if aut.num_states() > FAIL_FAST_STATES:
        raise ValueError(
            f"formula {text!r} needs about {aut.num_states()} automaton states (Spot's automaton); "
            f"at most {MAX_STATES} are supported"
        )
    return aut


def _allowed(aps: list[str], minterms: np.ndarray) -> spot.formula:
    """The projected alphabet as a Boolean formula (true when every assignment is allowed)."""
    if len(minterms) == 2 ** len(aps):
        return spot.formula.tt()
    terms = []
    for row in minterms:
        lits = [spot.formula.ap(ap) if val else spot.formula.Not(spot.formula.ap(ap))
                for ap, val in zip(aps, row)]
        terms.append(spot.formula.And(lits))
    return spot.formula.Or(terms)


def _edge_table(aut: spot.twa_graph, aps: list[str], minterms: np.ndarray):
    """Successor (-1 = none) and acceptance-mark set of every (state, minterm)."""
    variables = [aut.register_ap(ap) for ap in aps]
    bdds = []
    for row in minterms:
        bdd = buddy.bddtrue
        for var, val in zip(variables, row):
            bdd = bdd & (buddy.bdd_ithvar(var) if val else buddy.bdd_nithvar(var))
        bdds.append(bdd)
    num = aut.num_states()
    dst = np.full((num, len(minterms)), -1, dtype=np.int64)
    marks = [[() for _ in minterms] for _ in range(num)]
    for state in range(num):
        for edge in aut.out(state):
            for col, bdd in enumerate(bdds):
                if dst[state, col] < 0 and (bdd & edge.cond) != buddy.bddfalse:
                    dst[state, col] = edge.dst
                    marks[state][col] = tuple(edge.acc.sets())
    return dst, marks


def _dba_tables(aut: spot.twa_graph, aps: list[str], minterms: np.ndarray):
    dst, marks = _edge_table(aut, aps, minterms)
    sink = aut.num_states()
    all_accepting = aut.acc().is_t()
    acc = np.array([[all_accepting or 0 in m for m in row] for row in marks], dtype=bool)
    delta = np.vstack([np.where(dst < 0, sink, dst), np.full((1, dst.shape[1]), sink)])
    accepting = np.vstack([acc & (dst >= 0), np.zeros((1, dst.shape[1]), dtype=bool)])
    epsilon = np.full((sink + 1, 1), -1)
    universal = graph.dba_universal(delta, accepting)
    return delta, accepting, epsilon, aut.get_init_state_number(), universal


def _ldba_tables(dpa: spot.twa_graph, aps: list[str], minterms: np.ndarray):
    """Initial part = the parity automaton; copy k per even colour; epsilon into accepting SCCs."""
    dst, marks = _edge_table(dpa, aps, minterms)
    sink = dpa.num_states()
    num = sink + 1
    base = np.vstack([np.where(dst < 0, sink, dst), np.full((1, dst.shape[1]), sink)])
    # missing edges and the sink get colour 1: odd, so rejecting under min-even parity
    color = np.ones_like(base)
    for state, row in enumerate(marks):
        for col, m in enumerate(row):
            if dst[state, col] >= 0:
                color[state, col] = m[0]
    evens = list(range(0, int(color.max()) + 1, 2))
    delta = [base]
    accepting = [np.zeros_like(base, dtype=bool)]
    epsilon = np.full((num * (1 + len(evens)), len(evens)), -1)
    for slot, k in enumerate(evens):
        offset = (1 + slot) * num
        kept = color >= k
        delta.append(np.where(kept, base + offset, sink))
        accepting.append(kept & (color == k))
        copy_reach = graph.reachability(graph.adjacency(np.where(kept, base, np.arange(num)[:, None])))
        on_cycle = (accepting[-1] & copy_reach[base, np.arange(num)[:, None]]).any(axis=1)
        in_accepting_scc = ((copy_reach & copy_reach.T) & on_cycle[None, :]).any(axis=1)
        src = np.nonzero(in_accepting_scc)[0]
        epsilon[src, slot] = src + offset
    delta = np.vstack(delta)
    accepting = np.vstack(accepting)
    universal = graph.dba_universal(delta, accepting)
    universal[:num] = graph.parity_universal(base, color)
    return delta, accepting, epsilon, dpa.get_init_state_number(), universal


def _finalize(delta, accepting, epsilon, init, universal, text) -> Automaton:
    """Trim, merge dead (and, for co-safe specs, universal) states, renumber breadth-first."""
    reach = graph.reachability(graph.adjacency(delta, epsilon))
    accepting = accepting & graph.internal(delta, reach)
    live = graph.nonempty(delta, accepting, epsilon)
    epsilon = np.where((epsilon >= 0) & live[np.maximum(epsilon, 0)], epsilon, -1)
    reachable = reach[init]
    no_epsilon = not (epsilon[reachable] >= 0).any()
    is_finite = no_epsilon and not (accepting & ~universal[:, None])[reachable].any()

    rep = np.arange(delta.shape[0])
    dead = np.nonzero(~live)[0]
    rep[dead] = dead[0] if len(dead) else 0
    if is_finite:
        good = np.nonzero(universal & live)[0]
        rep[good] = good[0]
        accepting = universal[delta]
    delta = rep[delta]
    epsilon = np.where(epsilon >= 0, rep[np.maximum(epsilon, 0)], -1)

    order = graph.bfs_order(int(rep[init]), delta, epsilon)
    if len(order) > MAX_STATES:
        raise ValueError(f"formula {text!r} needs {len(order)} automaton states; at most "
                         f"{MAX_STATES} are supported")
    new = np.full(delta.shape[0], -1)
    new[order] = np.arange(len(order))
    delta = new[delta[order]].astype(np.int32)
    eps = epsilon[order]
    eps = np.where(eps >= 0, new[np.maximum(eps, 0)], -1)
    width = max(1, int((eps >= 0).sum(axis=1).max()))
    eps = np.array([sorted(r[r >= 0]) + [-1] * (width - (r >= 0).sum()) for r in eps],
                   dtype=np.int32).reshape(len(order), width)
    return Automaton(
        delta=delta,
        accepting=accepting[order],
        epsilon=eps,
        success=(universal & live)[order],
        violation=~live[order],
        init=0,
        is_finite=bool(is_finite),
    )


def zero_or_one(num_props: int) -> np.ndarray:
    """`bool[P + 1, P]`: nothing true (row 0) or exactly proposition i-1 true (row i)."""
    return np.vstack([np.zeros((1, num_props), dtype=bool), np.eye(num_props, dtype=bool)])


def all_subsets(num_props: int) -> np.ndarray:
    """`bool[2**P, P]`: every assignment, row i = the binary digits of i (proposition 0 = LSB)."""
    return np.array(list(itertools.product((False, True), repeat=num_props)), dtype=bool)[
        :, ::-1
    ].reshape(2**num_props, num_props)


def product(*alphabets: np.ndarray) -> np.ndarray:
    """`bool[prod A_i, sum P_i]`: one row of each alphabet side by side (e.g. one per agent)."""
    rows = [np.concatenate(combo) for combo in itertools.product(*alphabets)]
    return np.array(rows, dtype=bool).reshape(-1, sum(a.shape[1] for a in alphabets))
