"""DFAs for RAD-Embeddings: minimisation, the reach-avoid-derived (RAD) sampler, banks of
conjunctions of DFAs (cDFAs) as padded arrays, and their tracking inside `jit`.

A DFA here is over a world's alphabet of A assignments (`env.alphabet`). The RAD sampler's
tokens are the non-empty assignments; the empty assignment (nothing true) is a self-loop in every
state, as the original leaves a DFA unchanged on an empty event (docs/fidelity.md).

Canonical form: every DFA is stored minimal (Moore's partition refinement over the states
reachable from the start) with its states numbered in breadth-first order from the start, symbols
in alphabet order. Two DFAs of one language therefore have equal arrays. Advancing a minimal DFA
to state q leaves the part reachable from q, which is again minimal: the tracker keeps q and
masks the rest (`reach`), so the graph a network reads depends on the residual language alone
(up to node order, which the encoder ignores).

RAD sampling (beyazit-x/rad-embeddings `src/dfa_samplers.py`, the NeurIPS'24 code):
- conjuncts n in 1..5, P(n) proportional to 0.5**n;
- each conjunct: k in 1..8 chain states, P(k) proportional to 0.5**k, plus an accepting sink
  (success) and a rejecting sink (fail). In each chain state the tokens are shuffled: the first
  leads on (to the next chain state, the last one to success), the second to fail, every other
  token stays with probability 0.9 and otherwise leads on or to fail with equal odds; minimised;
- then 0..5 mutations (uniform count), each: one uniformly drawn (state, token) redirected to a
  uniformly drawn state, accepting states made sinks, minimised; a mutation that leaves a single
  state is skipped;
- the whole conjunction is drawn again while its language (the product) is empty.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

MAX_CONJUNCTS = 5
MAX_CHAIN_STATES = 8
MAX_MUTATIONS = 5
STUTTER_PROB = 0.9
GEOMETRIC_P = 0.5


class DFA(NamedTuple):
    """A host-side DFA: `delta` int[S, A] next state per symbol, `accepting` bool[S], `start`."""

    delta: np.ndarray
    accepting: np.ndarray
    start: int

    @property
    def num_states(self) -> int:
        return int(self.delta.shape[0])


def minimise(dfa: DFA) -> tuple[DFA, np.ndarray]:
    """The minimal DFA of `dfa`'s language in canonical numbering (start 0, breadth-first over
    symbols in order), and the map old state -> new state (-1: unreachable from the start).

    Plain Python over lists: the DFAs are tiny (at most tens of states), where numpy's per-call
    overhead dominated the bank build."""
    rows = np.asarray(dfa.delta, np.int64).tolist()
    accepting = np.asarray(dfa.accepting, bool).tolist()
    num_states, num_symbols = len(rows), len(rows[0])
    start = int(dfa.start)
    reached, queue = {start}, [start]
    for s in queue:
        for t in rows[s]:
            if t not in reached:
                reached.add(t)
                queue.append(t)
    states = sorted(reached)
    # Moore refinement: split blocks by (own block, successors' blocks) until none splits
    block = {s: int(accepting[s]) for s in states}
    count = len(set(block.values()))
    while True:
        labels: dict[tuple, int] = {}
        block = {s: labels.setdefault((block[s], *(block[t] for t in rows[s])), len(labels))
                 for s in states}
        if len(labels) == count:
            break
        count = len(labels)
    rep = {}
    for s in states:
        rep.setdefault(block[s], s)
    # breadth-first numbering from the start's block
    order = {block[start]: 0}
    queue = [block[start]]
    for b in queue:
        for t in rows[rep[b]]:
            if block[t] not in order:
                order[block[t]] = len(order)
                queue.append(block[t])
    new_delta = np.zeros((len(order), num_symbols), np.int32)
    new_accepting = np.zeros(len(order), bool)
    for b, i in order.items():
        new_delta[i] = [order[block[t]] for t in rows[rep[b]]]
        new_accepting[i] = accepting[rep[b]]
    state_map = np.full(num_states, -1, np.int32)
    for s in states:
        state_map[s] = order[block[s]]
    return DFA(new_delta, new_accepting, 0), state_map


def live_states(dfa: DFA) -> np.ndarray:
    """bool[S]: an accepting state is reachable from the state."""
    live = np.asarray(dfa.accepting, bool).copy()
    while True:
        grown = live | live[dfa.delta].any(axis=1)
        if (grown == live).all():
            return live
        live = grown


def reach_table(dfa: DFA) -> np.ndarray:
    """bool[S, S]: `reach[s, t]`, state t is reachable from s (reflexive)."""
    num_states = dfa.num_states
    reach = np.eye(num_states, dtype=bool)
    step = np.zeros((num_states, num_states), bool)
    step[np.repeat(np.arange(num_states), dfa.delta.shape[1]), dfa.delta.reshape(-1)] = True
    while True:
        grown = reach | ((reach.astype(np.int32) @ step.astype(np.int32)) > 0)
        if (grown == reach).all():
            return reach
        reach = grown


def product_is_empty(dfas: Sequence[DFA]) -> bool:
    """True if no word is accepted by every DFA (breadth-first search of the product)."""
    start = tuple(d.start for d in dfas)
    seen, queue = {start}, [start]
    num_symbols = dfas[0].delta.shape[1]
    while queue:
        state = queue.pop()
        if all(d.accepting[s] for d, s in zip(dfas, state)):
            return False
        for a in range(num_symbols):
            nxt = tuple(int(d.delta[s, a]) for d, s in zip(dfas, state))
            if nxt not in seen:
                seen.add(nxt)
                queue.append(nxt)
    return True


def tokens_of(alphabet: np.ndarray) -> np.ndarray:
    """int[T]: the alphabet rows the RAD sampler uses as tokens (every non-empty assignment)."""
    tokens = np.flatnonzero(np.asarray(alphabet, bool).any(axis=1))
    if tokens.size < 2:
        raise ValueError(f"the RAD sampler needs at least 2 non-empty assignments in the "
                         f"alphabet, got {tokens.size} (alphabet shape {np.shape(alphabet)})")
    return tokens


def _truncated_geometric(rng: np.random.Generator, high: int) -> int:
    values = np.arange(1, high + 1)
    p = GEOMETRIC_P ** values
    return int(rng.choice(values, p=p / p.sum()))


def sample_reach_avoid(rng: np.random.Generator, tokens: np.ndarray, num_symbols: int) -> DFA:
    """One minimised reach-avoid chain DFA (before mutations)."""
    chain = _truncated_geometric(rng, MAX_CHAIN_STATES)
    success, fail = chain, chain + 1
    delta = np.tile(np.arange(chain + 2)[:, None], (1, num_symbols))
    for state in range(chain):
        order = rng.permutation(tokens)
        delta[state, order[0]] = state + 1
        delta[state, order[1]] = fail
        for token in order[2:]:
            if rng.random() > STUTTER_PROB:
                delta[state, token] = state + 1 if rng.random() < 0.5 else fail
    accepting = np.zeros(chain + 2, bool)
    accepting[success] = True
    return minimise(DFA(delta, accepting, 0))[0]


def mutate(rng: np.random.Generator, dfa: DFA, tokens: np.ndarray) -> DFA | None:
    """One mutation: a random (state, token) redirected to a random state, accepting states made
    sinks, minimised; None where the result has a single state."""
    delta = dfa.delta.copy()
    source, target = rng.integers(dfa.num_states), rng.integers(dfa.num_states)
    delta[source, tokens[rng.integers(tokens.size)]] = target
    sinks = np.flatnonzero(dfa.accepting)
    delta[sinks] = sinks[:, None]
    out = minimise(DFA(delta, dfa.accepting, dfa.start))[0]
    return None if out.num_states == 1 else out


def sample_rad_dfa(rng: np.random.Generator, tokens: np.ndarray, num_symbols: int) -> DFA:
    """One reach-avoid-derived DFA: a chain DFA and 0..5 mutations."""
    dfa = sample_reach_avoid(rng, tokens, num_symbols)
    for _ in range(int(rng.integers(0, MAX_MUTATIONS + 1))):
        mutated = mutate(rng, dfa, tokens)
        if mutated is not None:
            dfa = mutated
    return dfa


def graph_size(cdfa: Sequence[DFA]) -> int:
    """Nodes of a conjunction's graph for RAD's encoder: one AND node, one per state, one per
    (state, distinct successor other than itself)."""
    size = 1
    for dfa in cdfa:
        for s in range(dfa.num_states):
            successors = np.unique(dfa.delta[s])
            size += 1 + int((successors != s).sum())
    return size


def sample_rad_cdfa(rng: np.random.Generator, alphabet: np.ndarray,
                    max_size: int | None = None) -> list[DFA]:
    """One RAD conjunction (1..5 DFAs) over `alphabet` bool[A, P], redrawn while empty (and,
    given `max_size`, while its graph has more nodes: a truncation of the original's
    distribution, docs/fidelity.md)."""
    tokens, num_symbols = tokens_of(alphabet), int(np.shape(alphabet)[0])
    while True:
        count = _truncated_geometric(rng, MAX_CONJUNCTS)
        dfas = [sample_rad_dfa(rng, tokens, num_symbols) for _ in range(count)]
        if max_size is not None and graph_size(dfas) > max_size:
            continue
        if not product_is_empty(dfas):
            return dfas


@struct.dataclass
class DFABank:
    """K conjunctions of at most N minimal DFAs of at most S states over A symbols.

    Attributes:
        delta: int32[K, N, S, A] next state (padded states and conjuncts: self-loops).
        accepting: bool[K, N, S]; unused conjuncts accept in state 0 (they never block success).
        live: bool[K, N, S] an accepting state is reachable.
        reach: bool[K, N, S, S] `reach[k, n, s, t]`: t is reachable from s.
        num_states: int32[K, N] states of each conjunct (0: unused conjunct).
        alphabet: bool[A, P] the assignment of each symbol.
    """

    delta: jax.Array
    accepting: jax.Array
    live: jax.Array
    reach: jax.Array
    num_states: jax.Array
    alphabet: jax.Array

    @property
    def size(self) -> int:
        return int(self.delta.shape[0])

    @property
    def max_conjuncts(self) -> int:
        return int(self.delta.shape[1])

    @property
    def max_states(self) -> int:
        return int(self.delta.shape[2])


def build_bank(cdfas: Sequence[Sequence[DFA]], alphabet: np.ndarray,
               max_conjuncts: int | None = None, max_states: int | None = None) -> DFABank:
    """Pad conjunctions of canonical minimal DFAs (each DFA is minimised again here) to a bank."""
    alphabet = np.asarray(alphabet, bool)
    num_symbols = alphabet.shape[0]
    cdfas = [[minimise(d)[0] for d in cdfa] for cdfa in cdfas]
    if not cdfas or any(not c for c in cdfas):
        raise ValueError("build_bank needs at least one conjunction, each of at least one DFA")
    for cdfa in cdfas:
        for d in cdfa:
            if d.delta.shape[1] != num_symbols:
                raise ValueError(f"a DFA over {d.delta.shape[1]} symbols; the alphabet has "
                                 f"{num_symbols}")
    n_max = max(len(c) for c in cdfas) if max_conjuncts is None else max_conjuncts
    s_max = max(d.num_states for c in cdfas for d in c) if max_states is None else max_states
    if any(len(c) > n_max for c in cdfas) or any(d.num_states > s_max for c in cdfas for d in c):
        raise ValueError(f"a conjunction exceeds max_conjuncts={n_max} or max_states={s_max}")
    k = len(cdfas)
    stay = np.arange(s_max, dtype=np.int32)[None, None, :, None]
    delta = np.tile(stay, (k, n_max, 1, num_symbols))
    accepting = np.zeros((k, n_max, s_max), bool)
    live = np.zeros((k, n_max, s_max), bool)
    reach = np.tile(np.eye(s_max, dtype=bool), (k, n_max, 1, 1))
    num_states = np.zeros((k, n_max), np.int32)
    for i, cdfa in enumerate(cdfas):
        for n, d in enumerate(cdfa):
            s = d.num_states
            delta[i, n, :s] = d.delta
            accepting[i, n, :s] = d.accepting
            live[i, n, :s] = live_states(d)
            reach[i, n, :s, :s] = reach_table(d)
            num_states[i, n] = s
        accepting[i, len(cdfa):, 0] = True
        live[i, len(cdfa):, 0] = True
    arrays = {"delta": delta, "accepting": accepting, "live": live, "reach": reach,
              "num_states": num_states, "alphabet": alphabet}
    return DFABank(**jax.device_put(arrays))


def sample_bank(num: int, alphabet: np.ndarray, seed: int = 0, max_size: int | None = None
                ) -> DFABank:
    """`num` RAD conjunctions over `alphabet` (graphs of at most `max_size` nodes if given),
    padded to 5 conjuncts of 10 states (the sampler's largest), so banks of one alphabet stack
    and share compilations."""
    if num < 1:
        raise ValueError(f"num must be >= 1, got {num}")
    rng = np.random.default_rng(seed)
    cdfas = [sample_rad_cdfa(rng, alphabet, max_size) for _ in range(num)]
    return build_bank(cdfas, alphabet, MAX_CONJUNCTS, MAX_CHAIN_STATES + 2)


def dfa_of_spec(spec) -> tuple[DFA, np.ndarray]:
    """A compiled co-safe spec (one unstacked `CompiledSpec`) as its minimal DFA of good prefixes
    (accepting = the spec's `success` states), and the map automaton state -> DFA state.

    Raises:
        ValueError: the spec is not co-safe (`is_finite` False): a DFA cannot decide it.
    """
    if not bool(np.asarray(spec.is_finite)):
        raise ValueError("RAD conditions on DFAs: only co-safe (finite-horizon) specs have one; "
                         "this spec is not co-safe (is_finite=False)")
    delta = np.asarray(spec.delta)
    delta = np.where(delta >= 0, delta, np.arange(delta.shape[0])[:, None])
    return minimise(DFA(delta, np.asarray(spec.success, bool), int(np.asarray(spec.init))))


def bank_of_specs(specs, max_conjuncts: int = 1, max_states: int | None = None
                  ) -> tuple[DFABank, np.ndarray]:
    """A stacked batch of compiled co-safe specs as a bank of one-DFA conjunctions, and the map
    int32[K, S_spec] automaton state -> DFA state (-1: unreachable), so a tracker may read the
    DFA state off the task loop's automaton state."""
    specs = jax.device_get(specs)
    num = int(np.shape(specs.delta)[0])
    dfas, maps = [], []
    for k in range(num):
        one = jax.tree.map(lambda x, k=k: x[k], specs)
        try:
            dfa, state_map = dfa_of_spec(one)
        except ValueError as err:
            raise ValueError(f"spec {k} of the bank: {err}") from None
        dfas.append([dfa])
        maps.append(state_map)
    bank = build_bank(dfas, np.asarray(specs.alphabet[0]), max_conjuncts, max_states)
    return bank, np.stack(maps).astype(np.int32)


# ---------------------------------------------------------------------------------------------
# Tracking inside jit


def advance(bank: DFABank, index: jax.Array, q: jax.Array, symbol: jax.Array) -> jax.Array:
    """int32[N]: every conjunct of cDFA `index` advanced from states `q` int32[N] on `symbol`."""
    conjunct = jnp.arange(q.shape[-1])
    return bank.delta[index, conjunct, q, symbol]


def status(bank: DFABank, index: jax.Array, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(success, violation) bool[]: every conjunct accepts; some conjunct can no longer accept.

    A conjunction whose conjuncts can each still accept but never together is not flagged
    (docs/fidelity.md); the sampler rejects such conjunctions at the start only.
    """
    conjunct = jnp.arange(q.shape[-1])
    success = jnp.all(bank.accepting[index, conjunct, q])
    violation = ~jnp.all(bank.live[index, conjunct, q])
    return success, violation
