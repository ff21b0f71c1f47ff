"""LTL progression on the device: LTL2Action's spec source.

The host enumerates, once per formula, every formula that LTL progression (Bacchus & Kabanza,
as LTL2Action runs it) can reach under the assignments of the world's alphabet, each result
simplified by Spot and kept in negation normal form. The closure becomes a transition table
over *formula states* (shared by all formulas of a bank: Spot's formulas are unique, so equal
progressions meet in one state) plus, per state, its syntax tree as a padded graph for the
R-GCN encoder. The episode steps that table inside `jit`.

Progression rules (assignment `s`): `p -> s(p)`, `X f -> f`, `F f -> F f | prog(f)`,
`G f -> G f & prog(f)`, `f U g -> prog(g) | (prog(f) & f U g)`, `f W g` likewise,
`f R g -> prog(g) & (prog(f) | f R g)`, `f M g` likewise; and/or component-wise. A task succeeds
when its formula progresses to `true` and is violated when it progresses to `false`.

Graphs follow LTL2Action's AST builder: one node per operator or terminal, an edge from each
child to its parent typed `arg` (unary), `arg1`/`arg2` (binary; n-ary and/or nest to the
right), and a self edge on every node. Spot's W, R, M, ->, <-> and xor are rewritten into the
original's vocabulary (next, until, and, or, eventually, always, not, True, False, propositions)
for the graph only (docs/fidelity.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import spot
from flax import struct

from specrl_jax.tasks.sources import Events

OPERATORS = ("next", "until", "and", "or", "eventually", "always", "not")
TRUE_TOKEN, FALSE_TOKEN = len(OPERATORS), len(OPERATORS) + 1
PROP_OFFSET = len(OPERATORS) + 2
#: node features: LTL2Action's 22-dim one-hot (7 operators, True, False, 13 terminal slots), wider
#: only for worlds of more than 13 propositions
MIN_FEATURES = 22
EDGE_SELF, EDGE_ARG, EDGE_ARG1, EDGE_ARG2 = 0, 1, 2, 3
NUM_EDGE_TYPES = 4
DEFAULT_MAX_STATES = 4096  # per formula
DEFAULT_MAX_NODES = 256  # per formula state's syntax tree

_UNARY = {spot.op_X: "next", spot.op_F: "eventually", spot.op_G: "always", spot.op_Not: "not"}
_BINARY = {spot.op_U: "until", spot.op_And: "and", spot.op_Or: "or"}


def num_features(num_props: int) -> int:
    """Width of the one-hot node features for a world of `num_props` propositions."""
    return max(MIN_FEATURES, PROP_OFFSET + num_props)


def _progress(f: spot.formula, true: frozenset[str],
              memo: dict[tuple[spot.formula, frozenset[str]], spot.formula]) -> spot.formula:
    """One progression step of an NNF formula under the propositions `true` (unsimplified)."""
    kind = f.kind()
    if kind in (spot.op_tt, spot.op_ff):
        return f
    if kind == spot.op_ap:
        return spot.formula.tt() if f.ap_name() in true else spot.formula.ff()
    if kind == spot.op_Not:
        return spot.formula.ff() if f[0].ap_name() in true else spot.formula.tt()
    key = (f, true)
    if key in memo:
        return memo[key]
    prog = lambda g: _progress(g, true, memo)
    if kind == spot.op_And:
        out = spot.formula.And([prog(c) for c in f])
    elif kind == spot.op_Or:
        out = spot.formula.Or([prog(c) for c in f])
    elif kind == spot.op_X:
        out = f[0]
    elif kind == spot.op_F:
        out = spot.formula.Or([f, prog(f[0])])
    elif kind == spot.op_G:
        out = spot.formula.And([f, prog(f[0])])
    elif kind in (spot.op_U, spot.op_W):
        out = spot.formula.Or([prog(f[1]), spot.formula.And([prog(f[0]), f])])
    elif kind in (spot.op_R, spot.op_M):
        out = spot.formula.And([prog(f[1]), spot.formula.Or([prog(f[0]), f])])
    else:
        raise ValueError(f"LTL progression does not cover the operator of {f} (kind {kind})")
    memo[key] = out
    return out


class Progressor:
    """Host progression with Spot simplification, memoised per (formula, relevant assignment)."""

    def __init__(self) -> None:
        self.simplifier = spot.tl_simplifier()
        self.memo: dict[tuple[spot.formula, frozenset[str]], spot.formula] = {}
        self.raw: dict[tuple[spot.formula, frozenset[str]], spot.formula] = {}
        self.aps: dict[spot.formula, frozenset[str]] = {}

    def normalise(self, f: spot.formula) -> spot.formula:
        f = spot.unabbreviate(f, "ei^")
        return spot.negative_normal_form(self.simplifier.simplify(spot.negative_normal_form(f)))

    def step(self, f: spot.formula, true: frozenset[str]) -> spot.formula:
        """The simplified progression of `f` under the propositions `true`."""
        aps = self.aps.get(f)
        if aps is None:
            aps = self.aps[f] = frozenset(str(a) for a in spot.atomic_prop_collect(f))
        key = (f, true & aps)
        if key not in self.memo:
            self.memo[key] = self.normalise(_progress(f, key[1], self.raw))
        return self.memo[key]


def formula_graph(f: spot.formula, propositions: Sequence[str]
                  ) -> tuple[list[int], list[int], list[int]]:
    """LTL2Action's syntax-tree graph of `f`: `(token, parent, edge type)` per node, preorder,
    root first (parent -1). Edges run child -> parent; the self edges are implicit."""
    index = {p: i for i, p in enumerate(propositions)}
    tokens: list[int] = []
    parents: list[int] = []
    edges: list[int] = []

    def visit(g: spot.formula, parent: int, edge: int) -> None:
        kind = g.kind()
        node = len(tokens)
        parents.append(parent)
        edges.append(edge)
        if kind == spot.op_tt:
            tokens.append(TRUE_TOKEN)
        elif kind == spot.op_ff:
            tokens.append(FALSE_TOKEN)
        elif kind == spot.op_ap:
            if g.ap_name() not in index:
                raise ValueError(f"proposition {g.ap_name()!r} is not one of the world's "
                                 f"{tuple(propositions)}")
            tokens.append(PROP_OFFSET + index[g.ap_name()])
        elif kind in _UNARY:
            tokens.append(OPERATORS.index(_UNARY[kind]))
            visit(g[0], node, EDGE_ARG)
        elif kind in _BINARY:
            tokens.append(OPERATORS.index(_BINARY[kind]))
            children = list(g)
            visit(children[0], node, EDGE_ARG1)
            join = spot.formula.And if kind == spot.op_And else spot.formula.Or
            rest = children[1] if len(children) == 2 else join(children[1:])
            visit(rest, node, EDGE_ARG2)
        else:
            raise ValueError(f"no graph node for the operator of {g} (kind {kind})")

    visit(spot.unabbreviate(f, "eiWMR^"), -1, EDGE_SELF)
    return tokens, parents, edges


@struct.dataclass
class ProgressionBank:
    """The progression closure of K formulas over an alphabet of A symbols (arrays only).

    Axes: S formula states (all formulas together), N graph nodes (padded).

    Attributes:
        delta: int32[S, A + 1] next state per symbol; column A (a label outside the alphabet)
            stays.
        is_true, is_false: bool[S] the state's formula is `true` / `false`.
        roots: int32[K] each formula's initial state.
        tokens: int16[S, N] node token (-1 padding); parent: int16[S, N] parent node (-1: root
            or padding); edge: int8[S, N] type of the edge to the parent.
        alphabet: bool[A, P].
    """

    delta: jax.Array
    is_true: jax.Array
    is_false: jax.Array
    roots: jax.Array
    tokens: jax.Array
    parent: jax.Array
    edge: jax.Array
    alphabet: jax.Array

    @property
    def num_states(self) -> int:
        return int(self.delta.shape[0])

    @property
    def num_formulas(self) -> int:
        return int(self.roots.shape[0])


def build_bank(formulas: Sequence[str], propositions: Sequence[str], alphabet: np.ndarray,
               max_states: int = DEFAULT_MAX_STATES, max_nodes: int = DEFAULT_MAX_NODES,
               progressor: Progressor | None = None) -> ProgressionBank:
    """Enumerate the progression closure of every formula over `alphabet` (host, Spot); see
    `closure` for the arguments."""
    return closure(formulas, propositions, alphabet, max_states, max_nodes, progressor)[0]


def closure(formulas: Sequence[str], propositions: Sequence[str], alphabet: np.ndarray,
            max_states: int = DEFAULT_MAX_STATES, max_nodes: int = DEFAULT_MAX_NODES,
            progressor: Progressor | None = None) -> tuple[ProgressionBank, list[spot.formula]]:
    """The progression closure of every formula over `alphabet` and its formula states (host).

    Args:
        formulas: K formula texts (Spot syntax) over `propositions`.
        propositions: the world's propositions (names), in the env's order.
        alphabet: bool[A, P] the assignments the world can produce.
        max_states: budget of distinct formula states reachable from one formula.
        max_nodes: budget of syntax-tree nodes of one formula state.

    Returns:
        `(bank, states)`: the tables and the formula of each state (row of the tables).

    Raises:
        ValueError: an empty list, a formula outside the world's propositions, or a closure /
            graph over its budget (the message names the formula and the budget).
    """
    alphabet = np.asarray(alphabet, bool)
    propositions = tuple(propositions)
    if not len(formulas):
        raise ValueError("need at least one formula")
    if alphabet.ndim != 2 or alphabet.shape[1] != len(propositions):
        raise ValueError(f"alphabet must be bool[A, {len(propositions)}], got shape "
                         f"{alphabet.shape}")
    prog = progressor or Progressor()
    symbols = [frozenset(p for p, on in zip(propositions, row) if on) for row in alphabet]
    ids: dict[spot.formula, int] = {}
    states: list[spot.formula] = []
    rows: list[list[int]] = []
    roots = []
    for text in formulas:
        root = prog.normalise(spot.formula(text))
        unknown = {str(a) for a in spot.atomic_prop_collect(root)} - set(propositions)
        if unknown:
            raise ValueError(f"formula {text!r} names {sorted(unknown)}, not among the world's "
                             f"propositions {propositions}")
        seen = {root}
        frontier = [root]
        while frontier:
            f = frontier.pop()
            if f not in ids:
                ids[f] = len(states)
                states.append(f)
                rows.append([prog.step(f, s) for s in symbols])
            for g in rows[ids[f]]:
                if g not in seen:
                    seen.add(g)
                    frontier.append(g)
            if len(seen) > max_states:
                raise ValueError(f"the progression closure of {text!r} exceeds the budget of "
                                 f"max_states={max_states} formula states")
        roots.append(ids[root])
    delta = np.array([[ids[g] for g in succ] + [i] for i, succ in enumerate(rows)], np.int32)
    graphs = [formula_graph(f, propositions) for f in states]
    num_nodes = max(len(g[0]) for g in graphs)
    if num_nodes > max_nodes:
        worst = states[int(np.argmax([len(g[0]) for g in graphs]))]
        raise ValueError(f"the syntax tree of {worst} has {num_nodes} nodes, over the budget of "
                         f"max_nodes={max_nodes}")
    tokens = np.full((len(states), num_nodes), -1, np.int16)
    parent = np.full((len(states), num_nodes), -1, np.int16)
    edge = np.zeros((len(states), num_nodes), np.int8)
    for i, (tok, par, edg) in enumerate(graphs):
        tokens[i, :len(tok)], parent[i, :len(par)], edge[i, :len(edg)] = tok, par, edg
    is_true = np.array([f.is_tt() for f in states])
    is_false = np.array([f.is_ff() for f in states])
    bank = ProgressionBank(jnp.asarray(delta), jnp.asarray(is_true), jnp.asarray(is_false),
                           jnp.asarray(roots, jnp.int32), jnp.asarray(tokens), jnp.asarray(parent),
                           jnp.asarray(edge), jnp.asarray(alphabet))
    return bank, states


@struct.dataclass
class ProgressionTask:
    """An episode's formula (index into the bank) and its current progressed formula state."""

    formula: jax.Array  # int32[]
    state: jax.Array  # int32[], row of the bank's tables
    task_id: jax.Array  # int32[], -1 (no curriculum)


def symbol_or_outside(alphabet: jax.Array, props: jax.Array) -> jax.Array:
    """int32[]: the alphabet row of the label `props` bool[P], or A where it is none."""
    match = jnp.all(alphabet == props.astype(bool)[None, :], axis=-1)
    return jnp.where(match.any(), jnp.argmax(match), alphabet.shape[0]).astype(jnp.int32)


def step_state(bank: ProgressionBank, state: jax.Array, props: jax.Array) -> jax.Array:
    """int32[]: the formula state after progressing `state` by the label `props` bool[P]."""
    return bank.delta[state, symbol_or_outside(bank.alphabet, props)]


class ProgressionSource:
    """LTL2Action's tasks for `tasks.TaskEnv`: a bank of formulas, each episode one of them
    (uniformly drawn, or the one at `index`), progressed by every label.

    Events: `success` (and `accepted`) when the formula progresses to true, `violation` when it
    progresses to false, `progress` when it changes otherwise.
    """

    def __init__(self, bank: ProgressionBank, alphabet: jax.Array):
        env_alphabet = np.asarray(alphabet, bool)
        if env_alphabet.shape[1] != bank.alphabet.shape[1]:
            raise ValueError(f"the bank is over {bank.alphabet.shape[1]} propositions, the world "
                             f"has {env_alphabet.shape[1]}")
        self.bank = bank
        self.num_tasks = bank.num_formulas
        self.may_take_epsilon = False
        self.symbol_is_row = bool(np.array_equal(np.asarray(bank.alphabet), env_alphabet))

    @property
    def specs(self) -> ProgressionBank:
        return self.bank

    def init_params(self) -> None:
        return None

    def reset(self, key: jax.Array, source_params: Any = None, index: jax.Array | None = None
              ) -> ProgressionTask:
        if index is None:
            index = jax.random.randint(key, (), 0, self.num_tasks)
        index = jnp.asarray(index, jnp.int32)
        return ProgressionTask(index, self.bank.roots[index], jnp.full((), -1, jnp.int32))

    def next_index(self, task: ProgressionTask) -> None:
        return None

    def takes_epsilon(self, task: ProgressionTask, slot: jax.Array) -> jax.Array:
        return jnp.zeros((), bool)

    def step(self, key: jax.Array, task: ProgressionTask, props: jax.Array,
             symbol: jax.Array | None,
             is_epsilon: jax.Array, slot: jax.Array, source_params: Any = None
             ) -> tuple[ProgressionTask, Events]:
        if symbol is None:
            symbol = symbol_or_outside(self.bank.alphabet, props)
        state = self.bank.delta[task.state, symbol]
        success, violation = self.bank.is_true[state], self.bank.is_false[state]
        progress = (state != task.state) & ~violation
        return task.replace(state=state), Events(progress, success, success, violation)
