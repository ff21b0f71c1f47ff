"""DeepLTL's candidate reach-avoid sequences of every automaton state, precomputed on the host.

The depth-first search of the reference (all simple paths into an accepting cycle, with its
containment pruning and avoid sets), loops unrolled twice for infinite-horizon specs and dropped
for co-safe ones; epsilon steps are marked. The search is memoised so that it is complete (see
`_Search`) within a budget; start states past it fall back to the shortest paths to acceptance
(`candidate_sequences`). Steps are stored as ids into a table of the distinct (reach, avoid,
epsilon slot) pairs.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from specrl_jax.automata import graph
from specrl_jax.automata.translate import Automaton

NUM_LOOPS_INFINITE = 2
MAX_PAIRS = 2**15 - 1
# limits of one search over an automaton, read when it starts; the paper's specs need at most
# 8,003 calls and 888,808 work units
SEARCH_BUDGET = 20_000  # memoised calls
WORK_BUDGET = 2_000_000  # path steps built plus containment checks made


@dataclasses.dataclass(frozen=True)
class Sequences:
    """Candidate sequences as ids into a table of their distinct reach-avoid pairs.

    Attributes:
        pair: int16[S, C, L] pair of each step (0, the padding pair, past the end).
        pair_reach, pair_avoid: bool[U, A] symbols to reach / avoid (reach empty for epsilon).
        pair_epsilon_slot: int32[U] epsilon edge to take, -1 if not an epsilon step.
        length: int32[S, C] steps of each sequence; valid: bool[S, C].
        complete: bool[S] the state's candidates are the complete search's (True where no
            search runs: dead and, for co-safe specs, success states).
        dropped: int32[S] candidates dropped by `max_length` / `max_sequences`.
    """

    pair: np.ndarray
    pair_reach: np.ndarray
    pair_avoid: np.ndarray
    pair_epsilon_slot: np.ndarray
    length: np.ndarray
    valid: np.ndarray
    complete: np.ndarray
    dropped: np.ndarray


class _Transition(NamedTuple):
    """A group of symbols from one state to one target with one acceptance flag, or an epsilon
    edge (slot >= 0, no symbols)."""

    source: int
    target: int
    accepting: bool
    slot: int  # epsilon slot, -1 for a labelled transition
    symbols: int  # bit mask of the alphabet rows taking it (0 for epsilon)
    dead: bool  # the target has an empty language


class _Path(NamedTuple):
    reach: tuple  # reach symbol mask of each step (what the containment pruning compares)
    steps: tuple  # ((transition, avoid symbol mask), ...)
    loop_state: int  # the state the accepting cycle returns to (a source of one of the steps)


def _mask(symbols) -> int:
    return sum(1 << int(a) for a in symbols)


def _transitions(aut: Automaton, q: int) -> list[_Transition]:
    out, dead = [], aut.violation.tolist()
    for t in sorted(set(aut.delta[q].tolist())):
        for acc in (False, True):
            syms = np.nonzero((aut.delta[q] == t) & (aut.accepting[q] == acc))[0]
            if len(syms):
                out.append(_Transition(q, t, acc, -1, _mask(syms), dead[t]))
    for slot, t in enumerate(aut.epsilon[q].tolist()):
        if t >= 0:
            out.append(_Transition(q, t, False, slot, 0, dead[t]))
    return out


def _contained(longer: tuple, shorter: tuple) -> bool:
    """The shorter path's reach sets embed, in order, as supersets of steps of the longer one
    (the reference's `check_path_contained`; greedy matching finds an embedding if any)."""
    pos = 0
    for reach in longer:
        if not reach & ~shorter[pos]:
            pos += 1
            if pos == len(shorter):
                return True
    return False


def _prune(paths: list[_Path], charge=lambda checks: None) -> list[_Path]:
    """Drop every path into which a strictly shorter one embeds (`_contained`).

    This is the reference's pairwise pruning. Embedding is transitive, so the paths it keeps
    are exactly those that no strictly shorter path embeds into, and checking against the
    shorter paths kept is enough. The order of the kept paths is the input order. `charge` is
    told the number of checks before they are made (it may raise to stop).
    """
    if len(paths) < 2:
        return paths
    keep = [False] * len(paths)
    shorter: list[tuple] = []  # distinct reach tuples kept, all shorter than the current length
    same: dict[tuple, None] = {}  # kept at the current length
    length = 0
    for i in sorted(range(len(paths)), key=lambda k: len(paths[k].reach)):
        reach = paths[i].reach
        if len(reach) != length:
            shorter += same
            same, length = {}, len(reach)
        charge(len(shorter))
        if not any(_contained(reach, o) for o in shorter):
            keep[i] = True
            same[reach] = None
    return [p for p, k in zip(paths, keep) if k]


def _bits(mask: int):
    while mask:
        low = mask & -mask
        yield low.bit_length() - 1
        mask ^= low


class _OverBudget(Exception):
    """The search needed more than its budget of memoised calls or work."""


def _shortest_only(aut: Automaton, out: list[list[_Transition]]) -> list[list[_Transition]]:
    """Keep the transitions on shortest paths to an accepting transition (and those into dead
    states, which become avoid sets); states with an accepting transition keep only those."""
    goal = aut.accepting.any(axis=1)
    adj = graph.adjacency(aut.delta, aut.epsilon) & ~aut.violation[None, :]
    dist = np.where(goal, 0, np.iinfo(np.int32).max)
    frontier = goal
    for k in range(1, aut.num_states + 1):
        frontier = adj[:, frontier].any(axis=1) & (dist > k)
        if not frontier.any():
            break
        dist[frontier] = k
    return [[t for t in ts if t.dead or (t.accepting if goal[q] else dist[t.target] == dist[q] - 1)]
            for q, ts in enumerate(out)]


class _Search:
    """The reference's depth-first search (no critic: obs is None), complete and memoised.

    The reference explores every simple path. What its call at state q returns depends on the
    path above q only through the states of q's SCC that the search from q can run into (a
    cycle closes only inside an SCC) and, among those, the ones at or before the latest
    accepting transition (a closed cycle is accepting iff it contains that transition). So
    calls agreeing on (q, those states, those before the accepting transition) return the same
    paths: each is computed once and shared by every start state. Sets are bit masks. Calls
    run on an explicit stack, so path length is not bounded by Python's recursion limit.

    The number of distinct calls, and of paths, can still grow exponentially (long reach-avoid
    chains, conjunctions of many `F`s); `_OverBudget` is raised once the search as a whole
    has made over `budget` calls or `work_budget` units of work (path steps built plus
    containment checks), both read from the module at construction unless given. With
    `shortest`, the search runs over `_shortest_only`'s transitions, where every cycle is
    accepting; with `cap`, each call keeps only its `cap` shortest paths.
    """

    def __init__(self, aut: Automaton, shortest: bool = False, cap: int | None = None,
                 budget: int | None = None, work_budget: int | None = None):
        self.out = [_transitions(aut, q) for q in range(aut.num_states)]
        if shortest:
            self.out = _shortest_only(aut, self.out)
        adj = np.zeros((aut.num_states,) * 2, dtype=bool)
        for q, out in enumerate(self.out):
            adj[q, [t.target for t in out]] = True
        reach = graph.reachability(adj)
        self.scc = [_mask(np.nonzero(row)[0]) for row in reach & reach.T]
        self.succ = [_mask({t.target for t in out if not t.dead}) & self.scc[q]
                     for q, out in enumerate(self.out)]
        self.memo: dict[tuple, tuple[_Path, ...]] = {}
        self.cap = cap
        self.budget = SEARCH_BUDGET if budget is None else budget
        self.work_budget = WORK_BUDGET if work_budget is None else work_budget
        self.calls = self.work = 0

    def paths(self, q: int) -> tuple[_Path, ...]:
        """All pruned paths from q into an accepting cycle, avoid sets attached.

        Raises `_OverBudget` when the budget runs out; what earlier start states returned is
        complete, and a later start state may still be served from the memo.
        """
        key = self._key(q, 0, 0)
        result = self.memo.get(key)
        stack = [] if result is not None else [self._call(*key)]
        while stack:
            try:
                child = stack[-1].send(result)
            except StopIteration as done:
                stack.pop()
                result = done.value
            else:
                result = self.memo.get(child)
                if result is None:
                    stack.append(self._call(*child))
        return result

    def _charge(self, work: int) -> None:
        self.work += work
        if self.work > self.work_budget:
            raise _OverBudget

    def _touched(self, q: int, above: int) -> int:
        """The states of `above` that the search from q can run into: successors of the states
        q reaches inside its SCC without entering `above`."""
        free = self.scc[q] & ~above
        seen = frontier = 1 << q
        touched = 0
        while frontier:
            nxt = 0
            for s in _bits(frontier):
                nxt |= self.succ[s]
            touched |= nxt
            frontier = nxt & free & ~seen
            seen |= frontier
        return touched & above

    def _key(self, q: int, above: int, before_acc: int) -> tuple[int, int, int]:
        """The memo key of the call at q, given the states of q's SCC above it on the path
        (`above`) and those of them at or before the latest accepting transition."""
        if above:
            above = self._touched(q, above)
            before_acc &= above
        return q, above, before_acc

    def _call(self, q: int, above: int, before_acc: int):
        """One call of the reference's search, as a generator: it yields the key of every call
        it makes, is sent that call's paths, and returns (and memoises) its own."""
        self.calls += 1
        if self.calls > self.budget:
            raise _OverBudget
        on_path = above | 1 << q
        neg, paths = 0, []
        for t in self.out[q]:
            if t.dead:
                neg |= t.symbols
                continue
            bit = 1 << t.target
            if bit & on_path:
                # t closes a cycle inside q's SCC, so its own accepting flag counts (the
                # reference's `stays_in_scc`); flags on transitions that leave an SCC (a
                # co-safe spec's transitions into its success state) are masked by `& scc`
                if t.accepting or bit & before_acc:
                    paths.append(_Path((t.symbols,), ((t, 0),), t.target))
                elif t.source != t.target:
                    neg |= t.symbols
                continue
            scc = self.scc[t.target]
            futures = yield self._key(t.target, on_path & scc,
                                      (on_path if t.accepting else before_acc) & scc)
            if not futures:
                neg |= t.symbols
            self._charge(sum(len(f.reach) for f in futures) + len(futures))
            paths += [_Path((t.symbols,) + f.reach, ((t, 0),) + f.steps, f.loop_state)
                      for f in futures]
        kept = _prune(paths, self._charge)
        if self.cap is not None and len(kept) > self.cap:
            shortest = sorted(range(len(kept)), key=lambda i: len(kept[i].reach))[: self.cap]
            kept = [kept[i] for i in sorted(shortest)]
        result = tuple(_Path(p.reach, ((p.steps[0][0], neg),) + p.steps[1:], p.loop_state)
                       for p in kept)
        self.memo[q, above, before_acc] = result
        return result


def _first_path(out: list[list[_Transition]], q: int) -> _Path:
    """The walk from q taking the first live transition of `out` (`_shortest_only`'s) at every
    state, up to its first repeated state: a simple path into a cycle, and the cycle is
    accepting (a walk that only shortens the distance to acceptance cannot close one)."""
    seen, steps = set(), []
    while q not in seen:
        seen.add(q)
        neg = 0
        for d in out[q]:
            if d.dead:
                neg |= d.symbols
        t = next(t for t in out[q] if not t.dead)
        steps.append((t, neg))
        q = t.target
    return _Path(tuple(t.symbols for t, _ in steps), tuple(steps), q)


def _all_paths(aut: Automaton, starts: list[int], cap: int) -> tuple[dict, list[int]]:
    """Paths from every start state, and the start states the complete search did not serve.

    Those get the paths of the shortest-path search (`cap` per call), and where that too is
    over budget, the single `_first_path`. Later states go first: their calls are shared by
    the earlier ones (the initial state last), so as many states as possible stay complete.
    """
    found, left, incomplete = {}, list(reversed(starts)), []
    for level, make in enumerate((lambda: _Search(aut),
                                  lambda: _Search(aut, shortest=True, cap=cap))):
        if not left:
            break
        search, pending, left = make(), left, []
        for q in pending:
            try:
                found[q] = search.paths(q)
            except _OverBudget:
                left.append(q)
        if level == 0:
            incomplete = left
    if left:
        out = _shortest_only(aut, [_transitions(aut, q) for q in range(aut.num_states)])
        found.update((q, (_first_path(out, q),)) for q in left)
    return found, incomplete


def _loop_index(path: _Path) -> int:
    return next(i for i, (t, _) in enumerate(path.steps) if t.source == path.loop_state)


def _sequence_length(path: _Path, num_loops: int) -> int:
    loop_index = _loop_index(path)
    return loop_index + (len(path.steps) - loop_index) * num_loops


def _to_sequence(path: _Path, num_loops: int) -> list[tuple[_Transition, int]]:
    loop_index = _loop_index(path)
    return list(path.steps[:loop_index] + path.steps[loop_index:] * num_loops)


def candidate_sequences(aut: Automaton, max_sequences: int, max_length: int) -> Sequences:
    """DeepLTL's candidate reach-avoid sequences from every live state, as padded arrays.

    The search is complete unless it runs over `SEARCH_BUDGET` calls or `WORK_BUDGET` work;
    then the start states it did not serve (`complete` False) get the shortest paths to
    acceptance instead (see `_all_paths`). Sequences longer than `max_length` are dropped and,
    past `max_sequences` per state, only the shortest are kept (stable order), counted in
    `dropped`. Nothing is warned here: `tensors.compile_spec` warns from the flags.
    """
    num_loops = 0 if aut.is_finite else NUM_LOOPS_INFINITE
    starts = [q for q in range(aut.num_states)
              if not (aut.violation[q] or (aut.is_finite and aut.success[q]))]
    found, incomplete = _all_paths(aut, starts, max_sequences)
    per_state = []
    dropped = np.zeros(aut.num_states, dtype=np.int32)
    for q in range(aut.num_states):
        paths = found.get(q, ())
        sizes = [_sequence_length(p, num_loops) for p in paths]
        kept = sorted((k for k, n in enumerate(sizes) if 0 < n <= max_length),
                      key=sizes.__getitem__)[:max_sequences]
        dropped[q] = len(paths) - len(kept)
        per_state.append([_to_sequence(paths[k], num_loops) for k in kept])
    # row 0 of the pair table is the padding pair: no reach, no avoid, no epsilon
    pairs: dict[tuple, int] = {(0, 0, -1): 0}
    num_seq = max(1, max(len(s) for s in per_state))
    length = max(1, max((len(x) for s in per_state for x in s), default=1))
    ids = np.zeros((aut.num_states, num_seq, length), dtype=np.int64)
    lengths = np.zeros((aut.num_states, num_seq), dtype=np.int32)
    for q, seqs in enumerate(per_state):
        for c, seq in enumerate(seqs):
            lengths[q, c] = len(seq)
            for i, (t, avoid_mask) in enumerate(seq):
                ids[q, c, i] = pairs.setdefault((t.symbols, avoid_mask, t.slot), len(pairs))
    if len(pairs) > MAX_PAIRS:
        raise ValueError(f"{len(pairs)} distinct reach-avoid pairs; at most {MAX_PAIRS} fit the "
                         "int16 pair ids")
    reach = np.zeros((len(pairs), aut.delta.shape[1]), dtype=bool)
    avoid = np.zeros_like(reach)
    slot = np.full(len(pairs), -1, dtype=np.int32)
    symbols = np.arange(aut.delta.shape[1])
    for (reach_mask, avoid_mask, eps_slot), u in pairs.items():
        reach[u] = [reach_mask >> int(a) & 1 for a in symbols]
        avoid[u] = [avoid_mask >> int(a) & 1 for a in symbols]
        slot[u] = eps_slot
    complete = np.ones(aut.num_states, dtype=bool)
    complete[incomplete] = False
    return Sequences(pair=ids.astype(np.int16), pair_reach=reach, pair_avoid=avoid,
                     pair_epsilon_slot=slot, length=lengths, valid=lengths > 0,
                     complete=complete, dropped=dropped)
