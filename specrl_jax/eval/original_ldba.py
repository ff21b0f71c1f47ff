"""Accepting visits counted on the original benchmark's automata, beside our own count.

The original code counts `num_accepting_visits` on Rabinizer 4 / Owl LDBAs (`ltl2ldba -p -d -e`,
transition-based Buchi, epsilon jumps as unlabelled edges). Their HOA text for every
infinite-horizon formula of the paper ships in `specs/data/original_ldbas.json`; this module
reads it into dense tensors over a world's alphabet and steps them inside `jit`, as an
evaluation-only tracker beside our Spot automaton (`mu_acc` stays ours). No Spot at run time.

Public API:

    ldbas = suite_ldbas("zone/infinite/per", env)   # stacked OriginalLDBA over env.alphabet,
                                                    # suite order; None if no formula has one
    ldbas = formula_ldbas(formulas, env)             # the same for any formula list
    ldba = jax.tree.map(lambda x: x[i], ldbas)       # episode's automaton (or vmap over i)
    tracker = init(ldba)                             # one (unstacked) automaton; vmap for stacks
    tracker, accepted = step(ldba, tracker, label, our_epsilon, rule="policy")
    tracker.visits                                   # int32[] accepting visits so far
    state(tracker), is_violated(ldba, tracker)       # current state (-1 dead), original's flag
    build_ldba(hoa_text, propositions, alphabet)     # any one HOA text -> OriginalLDBA
    original_hoa(formula) / suite_formulas(name)     # the shipped HOA texts

`label` is either `info["propositions"]` (bool[P]) or the alphabet row (an integer symbol).
`our_epsilon` says our own step was an epsilon step (no env step, no label). Step the tracker
on every step of our episode and stop with it (the original's own violation does not end our
episode; `is_violated` reports it). Entries with `present` False count 0.

Epsilon rules (a static argument; docs/fidelity.md, Evaluation, row "Owl's
counts"):

* "policy" (default): the original's DeepLTL takes an epsilon edge only on the policy's
  epsilon action (the env is not stepped, the LDBA follows the state's unique edge). Our
  policies act on our automaton, so the original's tracker jumps when ours does; if its state
  has no epsilon edge at that moment the jump stays pending and is taken as soon as the
  tracker is in a state that has one (before the next label is read). A policy that never
  jumps never jumps here either (the original GenZ-LTL's tracker ignores epsilon edges too).
  A followed run that dies while the run that never jumped is alive falls back to the latter
  (a wrong guess, as our task's `tasks.sources.fall_back_run`); the pending jump is dropped,
  and the tracker jumps again when ours does.
* "hindsight": policy-independent; the tracker follows every run of the LDBA at once (all
  jump times) and reports the most accepting visits any run has made, dead runs included:
  the best single run, an upper bound of "policy" on the same labels until "policy" falls
  back (it does not fall back: a policy that jumps again after one can count more).

Both rules read labels deterministically (Owl's labelled edges are deterministic; the original
takes the first matching edge, and so does this parser). A label that leaves the automaton
(no edge: the original's completion sink) kills the run; `is_violated` is the original's
violation flag: every live run sits in a bottom SCC without an accepting transition.

The fall-back is well-defined on any automaton read here, since labelled edges are read
deterministically: the run that never jumped is unique. On the shipped automata it is also
Owl's initial component: epsilon edges appear only in the nine persistence LDBAs, from the
start state (the only state that labels reach from `Start:`, with no accepting edge) into a
component that labels alone never leave and that has no epsilon edge; that start state's
only labelled edge loops on the labels the formula allows, so the run that never jumped dies
exactly when the formula is violated (another colour), as ours
(`test_original_ldba.py::test_shipped_epsilon_edges_leave_a_deterministic_initial_part`).
"""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Sequence
from importlib import resources
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

RULES = ("policy", "hindsight")
Rule = Literal["policy", "hindsight"]


@struct.dataclass
class OriginalLDBA:
    """One original LDBA over a world's alphabet (arrays only; stacks carry a leading axis).

    Axes: S automaton states (HOA ids; padded states are unreachable), A alphabet symbols,
    E epsilon slots, P propositions.

    Attributes:
        delta: int32[S, A] next state per symbol, -1 where no edge (the original's sink).
        accepting: bool[S, A] the edge taken on the symbol is accepting (`{0}`).
        epsilon: int32[S, E] epsilon successors in HOA order, -1 padded.
        closure: bool[S, S] reflexive-transitive closure of the epsilon edges.
        violating: bool[S] the original's violation flag: bottom SCC (pruned edges, epsilon
            edges and the sink counted) without an accepting edge inside.
        init: int32[] the HOA's `Start:` state.
        present: bool[] an original automaton exists (False for padding entries of a stack).
        alphabet: bool[A, P] the world's assignments, rows = symbols.
    """

    delta: jnp.ndarray
    accepting: jnp.ndarray
    epsilon: jnp.ndarray
    closure: jnp.ndarray
    violating: jnp.ndarray
    init: jnp.ndarray
    present: jnp.ndarray
    alphabet: jnp.ndarray


@struct.dataclass
class TrackerState:
    """The tracker's state for one episode.

    Attributes:
        counts: int32[S] most accepting visits of a live run now in each state, -1 where no
            run is ("policy": at most one entry >= 0).
        visits: int32[] accepting visits counted so far (the most of any run, dead ones too).
        pending: bool[] "policy": our automaton jumped, the original's has not yet.
        free: int32[] "policy": the state of the run that never took an epsilon edge, -1 dead.
    """

    counts: jnp.ndarray
    visits: jnp.ndarray
    pending: jnp.ndarray
    free: jnp.ndarray


# ---------------------------------------------------------------------------------------------
# shipped data


@functools.cache
def _data() -> dict[str, Any]:
    with resources.files("specrl_jax.specs").joinpath("data", "original_ldbas.json").open() as f:
        return json.load(f)


@functools.cache
def _hoa_by_formula() -> dict[str, str]:
    return {e["formula"]: e["hoa"] for entries in _data()["suites"].values() for e in entries}


def original_hoa(formula: str) -> str | None:
    """The original's HOA text for a formula (exact text of a paper suite row), or None."""
    return _hoa_by_formula().get(formula)


def suite_formulas(name: str) -> list[str]:
    """Formulas of a suite that has original automata, in suite order (JSON order)."""
    suites = _data()["suites"]
    if name not in suites:
        raise ValueError(f"no original automata for suite {name!r}; suites with them: "
                         f"{', '.join(sorted(suites))}")
    return [e["formula"] for e in suites[name]]


# ---------------------------------------------------------------------------------------------
# HOA text -> host tables

_TOKEN = re.compile(r"\s*(\d+|[tf]|[!&|()])")


def _label_values(label: str, ap_values: np.ndarray) -> np.ndarray:
    """bool[A]: a HOA label (`t`, `f`, AP indices, `!`, `&`, `|`, parentheses; `!` > `&` > `|`)
    evaluated on every row of `ap_values` bool[A, N]."""
    tokens, pos = [], 0
    while pos < len(label.rstrip()):
        match = _TOKEN.match(label, pos)
        if match is None:
            raise ValueError(f"cannot read HOA label {label!r} at {label[pos:]!r}")
        tokens.append(match.group(1))
        pos = match.end()
    tokens.append("")
    index = [0]

    def peek() -> str:
        return tokens[index[0]]

    def take(expected: str | None = None) -> str:
        token = tokens[index[0]]
        if expected is not None and token != expected:
            raise ValueError(f"HOA label {label!r}: expected {expected!r}, found {token!r}")
        index[0] += 1
        return token

    def disjunction() -> np.ndarray:
        value = conjunction()
        while peek() == "|":
            take()
            value = value | conjunction()
        return value

    def conjunction() -> np.ndarray:
        value = unary()
        while peek() == "&":
            take()
            value = value & unary()
        return value

    def unary() -> np.ndarray:
        token = take()
        if token == "!":
            return ~unary()
        if token == "(":
            value = disjunction()
            take(")")
            return value
        if token in ("t", "f"):
            return np.full(ap_values.shape[0], token == "t")
        if token.isdigit() and int(token) < ap_values.shape[1]:
            return ap_values[:, int(token)].copy()
        raise ValueError(f"HOA label {label!r}: unexpected token {token!r}")

    value = disjunction()
    take("")
    return value


def _read_hoa(text: str) -> tuple[int, list[str], dict[int, list[tuple[str | None, int, bool]]]]:
    """(start state, AP names, state -> edges (label or None for epsilon, target, accepting))."""
    if "--BODY--" not in text:
        raise ValueError("HOA text without --BODY--")
    header, body = text.split("--BODY--", 1)
    fields = dict(line.split(":", 1) for line in header.strip().splitlines() if ":" in line)
    if "Start" not in fields:
        raise ValueError("HOA text without a Start: line (an empty language in Owl's output)")
    if fields.get("Acceptance", "").split() != ["1", "Inf(0)"]:
        raise ValueError(f"only Buchi acceptance '1 Inf(0)' is read, got "
                         f"{fields.get('Acceptance')}")
    count, *names = re.findall(r'\d+|"[^"]*"', fields["AP"])
    names = [n.strip('"') for n in names]
    if len(names) != int(count):
        raise ValueError(f"HOA AP line names {len(names)} propositions, announces {count}")
    edges: dict[int, list[tuple[str | None, int, bool]]] = {}
    current = None
    edge_line = re.compile(r"^(?:\[(?P<label>[^\]]*)\])?\s*(?P<dst>\d+)\s*(?P<acc>\{[^}]*\})?$")
    for line in body.split("--END--")[0].strip().splitlines():
        line = line.strip()
        if line.startswith("State:"):
            parts = line.split()
            if len(parts) != 2:
                raise ValueError(f"HOA state line {line!r}: state-based acceptance is not read")
            current = int(parts[1])
            edges.setdefault(current, [])
            continue
        match = edge_line.match(line)
        if match is None or current is None:
            raise ValueError(f"cannot read HOA body line {line!r}")
        acc = match["acc"]
        if acc not in (None, "{0}"):
            raise ValueError(f"HOA body line {line!r}: only acceptance set {{0}} is read")
        edges[current].append((match["label"], int(match["dst"]), acc is not None))
    return int(fields["Start"]), names, edges


def _transitive(adj: np.ndarray) -> np.ndarray:
    """bool[N, N]: reflexive-transitive closure of an adjacency matrix (repeated squaring)."""
    reach = adj | np.eye(adj.shape[0], dtype=bool)
    for _ in range(max(1, int(np.ceil(np.log2(adj.shape[0] + 1))))):
        reach = (reach.astype(np.int32) @ reach.astype(np.int32)) > 0
    return reach


def _violating(delta: np.ndarray, accepting: np.ndarray, epsilon: np.ndarray) -> np.ndarray:
    """bool[S]: the state's SCC is bottom (no edge, epsilon ones included, leaves it; an edge to
    the sink leaves it) and holds no accepting edge between two of its states."""
    num = delta.shape[0]
    sink = num  # one extra node: a bottom SCC without accepting edges
    adj = np.zeros((num + 1, num + 1), bool)
    adj[np.repeat(np.arange(num), delta.shape[1]), np.where(delta >= 0, delta, sink).ravel()] = 1
    keep = epsilon.ravel() >= 0
    adj[np.repeat(np.arange(num), epsilon.shape[1])[keep], epsilon.ravel()[keep]] = True
    adj[sink, sink] = True
    reach = _transitive(adj)
    same = reach & reach.T
    out = (same.astype(np.int32) @ adj.astype(np.int32)) > 0
    leaves = (out & ~same).any(axis=1)[:num]
    inside = np.take_along_axis(same[:num, :num], np.maximum(delta, 0), axis=1) & (delta >= 0)
    acc_edge = (accepting & inside).any(axis=1)
    acc_scc = (same[:num, :num] & acc_edge[None, :]).any(axis=1)
    return ~leaves & ~acc_scc


def build_ldba(hoa: str, propositions: Sequence[str], alphabet: np.ndarray) -> OriginalLDBA:
    """Dense tensors of one Owl HOA text over a world's alphabet.

    Like the original pipeline: every labelled edge is evaluated on the alphabet (pruning), the
    first matching edge of a state wins, symbols with no edge go to the sink (-1).

    Args:
        hoa: HOA text with epsilon edges as bare target lines (Owl's `-e` output).
        propositions: the world's proposition names (`env.propositions`); every HOA AP must be
            one of them (matched by name).
        alphabet: bool[A, P] the world's assignments (`env.alphabet`).

    Raises:
        ValueError: unreadable HOA, an AP the world lacks, or an alphabet of the wrong width.
    """
    propositions = tuple(propositions)
    alphabet = np.asarray(alphabet, bool)
    if alphabet.ndim != 2 or alphabet.shape[1] != len(propositions):
        raise ValueError(f"alphabet must be bool[A, {len(propositions)}] over {propositions}, "
                         f"got shape {alphabet.shape}")
    start, names, edges = _read_hoa(hoa)
    missing = [n for n in names if n not in propositions]
    if missing:
        raise ValueError(f"HOA propositions {missing} are not world propositions {propositions}")
    ap_values = alphabet[:, [propositions.index(n) for n in names]]
    ids = [start, *edges, *(t for out in edges.values() for _, t, _ in out)]
    num, num_symbols = max(ids) + 1, alphabet.shape[0]
    delta = np.full((num, num_symbols), -1, np.int32)
    accepting = np.zeros((num, num_symbols), bool)
    eps_lists: list[list[int]] = [[] for _ in range(num)]
    for q, out in edges.items():
        for label, target, acc in out:
            if label is None:
                eps_lists[q].append(target)
                continue
            fresh = _label_values(label, ap_values) & (delta[q] < 0)
            delta[q, fresh] = target
            accepting[q, fresh] = acc
    epsilon = np.full((num, max(1, max(len(e) for e in eps_lists))), -1, np.int32)
    for q, targets in enumerate(eps_lists):
        epsilon[q, : len(targets)] = targets
    eps_adj = np.zeros((num, num), bool)
    keep = epsilon.ravel() >= 0
    eps_adj[np.repeat(np.arange(num), epsilon.shape[1])[keep], epsilon.ravel()[keep]] = True
    closure = _transitive(eps_adj)
    return OriginalLDBA(
        delta=jnp.asarray(delta), accepting=jnp.asarray(accepting), epsilon=jnp.asarray(epsilon),
        closure=jnp.asarray(closure), violating=jnp.asarray(_violating(delta, accepting, epsilon)),
        init=jnp.int32(start), present=jnp.bool_(True), alphabet=jnp.asarray(alphabet))


# ---------------------------------------------------------------------------------------------
# stacks and suites


def _absent(num_symbols: int, alphabet: np.ndarray) -> dict[str, np.ndarray]:
    """A one-state placeholder: every symbol leads to the sink, `present` False."""
    return {"delta": np.full((1, num_symbols), -1, np.int32),
            "accepting": np.zeros((1, num_symbols), bool), "epsilon": np.full((1, 1), -1, np.int32),
            "closure": np.ones((1, 1), bool), "violating": np.ones(1, bool),
            "init": np.int32(0), "present": np.bool_(False), "alphabet": alphabet}


_PAD = {"delta": (("S", "-"), -1), "accepting": (("S", "-"), False),
        "epsilon": (("S", "E"), -1), "closure": (("S", "S"), False),
        "violating": (("S",), True), "init": ((), 0), "present": ((), False),
        "alphabet": (("-", "-"), False)}


def stack_ldbas(ldbas: Sequence[OriginalLDBA | None], alphabet: np.ndarray) -> OriginalLDBA:
    """Pad to common S and E and stack along a new leading axis; None entries become
    placeholders with `present` False (their tracker is dead from the start and counts 0).

    Args:
        ldbas: automata built over `alphabet`, or None.
        alphabet: bool[A, P] the shared alphabet.
    """
    alphabet = np.asarray(alphabet, bool)
    if not ldbas:
        raise ValueError("stack_ldbas needs at least one entry")
    tables = []
    for i, ldba in enumerate(ldbas):
        if ldba is None:
            tables.append(_absent(alphabet.shape[0], alphabet))
            continue
        if not isinstance(ldba, OriginalLDBA) or np.ndim(ldba.delta) != 2:
            raise TypeError(f"entry {i} is not an unstacked OriginalLDBA or None")
        if not np.array_equal(np.asarray(ldba.alphabet), alphabet):
            raise ValueError(f"entry {i} was built over another alphabet")
        tables.append({name: np.asarray(getattr(ldba, name)) for name in _PAD})
    size = {"S": max(t["delta"].shape[0] for t in tables),
            "E": max(t["epsilon"].shape[1] for t in tables)}
    out = {}
    for name, (axes, fill) in _PAD.items():
        padded = []
        for t in tables:
            arr = t[name]
            widths = [(0, size[ax] - arr.shape[d]) if ax in size else (0, 0)
                      for d, ax in enumerate(axes)]
            padded.append(np.pad(arr, widths, constant_values=fill) if axes else arr)
        out[name] = np.stack(padded)
    return OriginalLDBA(**jax.device_put(out))


def formula_ldbas(formulas: Sequence[str], env: Any) -> OriginalLDBA | None:
    """The original automata of any formula list (e.g. several suites' formulas concatenated, as
    the evaluator stacks them), in order, over the world's alphabet.

    Args:
        formulas: formula texts; matched by exact text with the paper's infinite-horizon rows.
        env: anything with `propositions` (names) and `alphabet` (bool[A, P]), e.g. a world.

    Returns:
        A stacked `OriginalLDBA` with a leading axis of `len(formulas)` (`present[i]` False
        where formula i has no original automaton), or None if none of them has one.
    """
    texts = [original_hoa(f) for f in formulas]
    if all(t is None for t in texts):
        return None
    alphabet = np.asarray(env.alphabet, bool)
    return stack_ldbas([None if t is None else build_ldba(t, env.propositions, alphabet)
                        for t in texts], alphabet)


def suite_ldbas(name: str, env: Any) -> OriginalLDBA | None:
    """`formula_ldbas` of a named suite's formulas (`specs.suite(name)`), in suite order; method
    suites (`deepltl/...`, `genz/...`) and finite suites have none and give None."""
    from specrl_jax import specs  # eval may use specs; imported here to keep import light

    return formula_ldbas(specs.suite(name), env)


# ---------------------------------------------------------------------------------------------
# the tracker (jittable; one unstacked automaton, vmap over stacks)


def init(ldba: OriginalLDBA) -> TrackerState:
    """The tracker at the start of an episode: one run in the initial state (none if absent)."""
    num = ldba.delta.shape[-2]
    counts = jnp.where((jnp.arange(num) == ldba.init) & ldba.present, 0, -1).astype(jnp.int32)
    free = jnp.where(ldba.present, ldba.init, -1).astype(jnp.int32)
    return TrackerState(counts=counts, visits=jnp.int32(0), pending=jnp.bool_(False), free=free)


def symbol_of(ldba: OriginalLDBA, props: jax.Array) -> jax.Array:
    """int32[]: the alphabet row equal to the label bool[P], -1 if none."""
    match = jnp.all(ldba.alphabet == props.astype(bool)[None, :], axis=-1)
    return jnp.where(match.any(), jnp.argmax(match), -1).astype(jnp.int32)


def _gather_max(counts: jax.Array, source_to_target: jax.Array) -> jax.Array:
    """int32[S]: new[r] = max over q with source_to_target[q, r] of counts[q] (-1 if none)."""
    return jnp.max(jnp.where(source_to_target, counts[:, None], -1), axis=0)


def _read(ldba: OriginalLDBA, counts: jax.Array, symbol: jax.Array) -> jax.Array:
    """Every run reads one symbol: deterministic edges, +1 on accepting ones, -1 (dead) at
    the sink. A symbol outside the alphabet leaves the runs where they are."""
    num_states, num_symbols = ldba.delta.shape
    column = jnp.clip(symbol, 0, num_symbols - 1)
    target = ldba.delta[:, column]
    moved = jnp.where(counts >= 0, counts + ldba.accepting[:, column], -1)
    new = _gather_max(moved, target[:, None] == jnp.arange(num_states)[None, :])
    return jnp.where((symbol >= 0) & (symbol < num_symbols), new, counts)


def _jump(ldba: OriginalLDBA, q: jax.Array, want: jax.Array) -> tuple[jax.Array, jax.Array]:
    """"policy": the run in state q (-1 dead) follows its state's first epsilon edge if `want`
    and there is one; returns (state, the jump is still wanted)."""
    edge = ldba.epsilon[jnp.maximum(q, 0), 0]
    can = (q >= 0) & (edge >= 0)
    return jnp.where(want & can, edge, q), want & ~can


def _read_run(ldba: OriginalLDBA, q: jax.Array, symbol: jax.Array, reads: jax.Array
              ) -> tuple[jax.Array, jax.Array]:
    """One run in state q (-1 dead) reads `symbol` where `reads` and the symbol is in the
    alphabet; returns (state, accepted bool[])."""
    num_symbols = ldba.delta.shape[1]
    reads = reads & (q >= 0) & (symbol >= 0) & (symbol < num_symbols)
    row, column = jnp.maximum(q, 0), jnp.clip(symbol, 0, num_symbols - 1)
    return (jnp.where(reads, ldba.delta[row, column], q),
            reads & ldba.accepting[row, column])


def _step_policy(ldba: OriginalLDBA, tracker: TrackerState, symbol: jax.Array,
                 our_epsilon: jax.Array) -> tuple[TrackerState, jax.Array]:
    """The followed run of the "policy" rule and the run that never jumps, by state (O(S) per
    step, no S x S work)."""
    num_states = ldba.delta.shape[0]
    q, pending = _jump(ldba, state(tracker), our_epsilon | tracker.pending)
    q, accepted = _read_run(ldba, q, symbol, ~our_epsilon)
    free, accepted_free = _read_run(ldba, tracker.free, symbol, ~our_epsilon)
    # the jumped run died, the formula is open: a wrong guess, not a violation (our task's rule)
    fell_back = (q < 0) & (free >= 0)
    q, accepted = jnp.where(fell_back, free, q), jnp.where(fell_back, accepted_free, accepted)
    pending = pending & ~fell_back
    # a pending jump is taken as soon as the run arrives in a state with an epsilon edge
    q_jumped, still = _jump(ldba, q, pending & ~our_epsilon)
    q, pending = q_jumped, jnp.where(our_epsilon, pending, still)
    visits = tracker.visits + accepted.astype(jnp.int32)
    counts = jnp.where(jnp.arange(num_states) == q, visits, -1).astype(jnp.int32)
    return TrackerState(counts=counts, visits=visits, pending=pending, free=free), accepted


def step(ldba: OriginalLDBA, tracker: TrackerState, label: jax.Array, our_epsilon: jax.Array,
         rule: Rule = "policy") -> tuple[TrackerState, jax.Array]:
    """One tracker step beside one step of ours.

    Args:
        ldba: one original automaton (unstacked; `jax.vmap` over a stack from `suite_ldbas`).
        tracker: its state (`init`).
        label: bool[P] `info["propositions"]`, or an integer alphabet row (the dtype decides);
            not read on an epsilon step of ours.
        our_epsilon: bool[] our step was an epsilon step (no env step, no label).
        rule: "policy" or "hindsight" (module docstring), static.

    Returns:
        (new tracker, accepted bool[]): whether an accepting edge was taken, i.e. `visits` went
        up by one (it rises by at most one per step under either rule).
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    label = jnp.asarray(label)
    symbol = (symbol_of(ldba, label) if label.dtype == jnp.bool_
              else label.astype(jnp.int32))
    our_epsilon = jnp.asarray(our_epsilon, bool)
    if rule == "policy":
        return _step_policy(ldba, tracker, symbol, our_epsilon)
    counts = jnp.where(our_epsilon, tracker.counts, _gather_max(tracker.counts, ldba.closure))
    counts = jnp.where(our_epsilon, counts, _read(ldba, counts, symbol))
    visits = jnp.maximum(tracker.visits, counts.max())
    new = TrackerState(counts=counts, visits=visits, pending=tracker.pending, free=tracker.free)
    return new, visits > tracker.visits


def state(tracker: TrackerState) -> jax.Array:
    """int32[]: the current state of the ("policy") run, -1 once dead (the original's sink);
    under "hindsight" the lowest state holding a live run."""
    alive = tracker.counts >= 0
    return jnp.where(alive.any(), jnp.argmax(alive), -1).astype(jnp.int32)


def is_violated(ldba: OriginalLDBA, tracker: TrackerState) -> jax.Array:
    """bool[]: the original's violation flag: no live run outside a violating state."""
    return ~jnp.any((tracker.counts >= 0) & ~ldba.violating)
