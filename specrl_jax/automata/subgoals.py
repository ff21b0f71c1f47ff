"""Reach-avoid subgoals of every automaton state, precomputed on the host as padded arrays.

Two kinds, both as masks over alphabet symbols:

* one-step subgoals (GenZ-LTL, GCRL-LTL): for each state, every labelled transition to another
  live state (reach = the symbols leading there, target = that state) plus, where the state has
  an accepting self-loop, "take it" (target = the state itself); avoid = the symbols leading to
  the dead sink. Epsilon transitions give no one-step subgoal.
* DeepLTL's candidate sequences: the depth-first search of the reference (all simple paths into
  an accepting cycle, with its containment pruning and avoid sets), loops unrolled twice for
  infinite-horizon specs and dropped for co-safe ones; epsilon steps are marked.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import NamedTuple

import numpy as np

from specrl_jax.automata.translate import Automaton

NUM_LOOPS_INFINITE = 2
SEARCH_BUDGET = 2_000  # depth-first calls per start state


@dataclasses.dataclass(frozen=True)
class Subgoals:
    """One-step subgoals: reach/avoid bool[S, G, A], target int32[S, G] (-1 unused), valid bool[S, G]."""

    reach: np.ndarray
    avoid: np.ndarray
    target: np.ndarray
    valid: np.ndarray


@dataclasses.dataclass(frozen=True)
class Sequences:
    """Candidate sequences: reach/avoid bool[S, C, L, A], epsilon bool[S, C, L],
    epsilon_slot int32[S, C, L] (which epsilon edge, -1 if not an epsilon step),
    length int32[S, C], valid bool[S, C]."""

    reach: np.ndarray
    avoid: np.ndarray
    epsilon: np.ndarray
    epsilon_slot: np.ndarray
    length: np.ndarray
    valid: np.ndarray


def one_step_subgoals(aut: Automaton) -> Subgoals:
    """Every labelled way out of each live state, plus its accepting self-loop if any."""
    per_state = []
    for q in range(aut.num_states):
        row, goals = aut.delta[q], []
        if not (aut.violation[q] or (aut.is_finite and aut.success[q])):
            for t in sorted(set(row.tolist()) - {q}):
                if not aut.violation[t]:
                    goals.append((t, row == t))
            loop = (row == q) & aut.accepting[q]
            if loop.any():
                goals.append((q, loop))
        per_state.append((goals, aut.violation[row]))
    num_goals = max(1, max(len(g) for g, _ in per_state))
    shape = (aut.num_states, num_goals)
    reach = np.zeros(shape + (aut.delta.shape[1],), dtype=bool)
    avoid = np.zeros_like(reach)
    target = np.full(shape, -1, dtype=np.int32)
    for q, (goals, dead) in enumerate(per_state):
        for g, (t, mask) in enumerate(goals):
            reach[q, g], avoid[q, g], target[q, g] = mask, dead, t
    return Subgoals(reach=reach, avoid=avoid, target=target, valid=target >= 0)


class _Transition:
    """A group of symbols from one state to one target with one acceptance flag, or an epsilon
    edge. Compared by identity: one object per (source, target, accepting, slot)."""

    __slots__ = ("accepting", "dead", "slot", "source", "symbols", "target")

    def __init__(self, source, target, accepting, slot, symbols, dead):
        self.source, self.target, self.accepting = source, target, accepting
        self.slot = slot  # epsilon slot, -1 for a labelled transition
        self.symbols = symbols  # frozenset of alphabet rows taking it (empty for epsilon)
        self.dead = dead  # the target has an empty language


class _Path(NamedTuple):
    steps: tuple  # ((transition, avoid: set of transitions), ...)
    loop_index: int


def _transitions(aut: Automaton, q: int) -> list[_Transition]:
    out, dead = [], aut.violation.tolist()
    for t in sorted(set(aut.delta[q].tolist())):
        for acc in (False, True):
            syms = np.nonzero((aut.delta[q] == t) & (aut.accepting[q] == acc))[0]
            if len(syms):
                out.append(_Transition(q, t, acc, -1, frozenset(syms.tolist()), dead[t]))
    for slot, t in enumerate(aut.epsilon[q].tolist()):
        if t >= 0:
            out.append(_Transition(q, t, False, slot, frozenset(), dead[t]))
    return out


def _contained(longer: _Path, shorter: _Path) -> bool:
    """The shorter path's reach sets embed, in order, as supersets of steps of the longer one."""
    pos = 0
    for step, _ in longer.steps:
        if step.symbols <= shorter.steps[pos][0].symbols:
            pos += 1
            if pos == len(shorter.steps):
                return True
    return False


def _prune(paths: list[_Path]) -> list[_Path]:
    if len(paths) < 2:
        return paths
    removed: set[int] = set()
    for i in range(len(paths)):
        for j in range(i + 1, len(paths)):
            if i in removed or j in removed:
                continue
            li, lj = len(paths[i].steps), len(paths[j].steps)
            if li < lj and _contained(paths[j], paths[i]):
                removed.add(j)
            elif li > lj and _contained(paths[i], paths[j]):
                removed.add(i)
            if i in removed:
                break
    return [p for k, p in enumerate(paths) if k not in removed]


class _Search:
    """The reference depth-first search over one automaton (no critic: obs is None)."""

    def __init__(self, aut: Automaton, max_depth: int, budget: int):
        self.aut = aut
        self.out = [_transitions(aut, q) for q in range(aut.num_states)]
        self.max_depth = max_depth
        self.budget = budget
        self.calls = 0
        self.cut = False  # a branch was left unexplored (depth or budget)

    def dfs(self, q: int, path: list, index: dict, acc_t: _Transition | None) -> list[_Path]:
        self.calls += 1
        index[q] = len(path)
        neg, paths = set(), []
        for t in self.out[q]:
            if t.dead:
                neg.add(t)
                continue
            path.append(t)
            # accepting flags only sit on SCC-internal transitions (translate._finalize)
            tracked = t if t.accepting else acc_t
            if t.target in index:
                if tracked in path[index[t.target]:]:
                    futures = [_Path((), index[t.target])]
                else:
                    path.pop()
                    if t.source != t.target:
                        neg.add(t)
                    continue
            elif len(path) >= self.max_depth or self.calls >= self.budget:
                # longer paths could only give sequences over max_length; not an avoid reason
                self.cut = True
                path.pop()
                continue
            else:
                futures = self.dfs(t.target, path, index, tracked)
                if not futures:
                    neg.add(t)
            paths += [_Path(((t, set()),) + f.steps, f.loop_index) for f in futures]
            path.pop()
        del index[q]
        paths = _prune(paths)
        for p in paths:
            p.steps[0][1].update(neg)
        return paths


def _search_within_budget(aut: Automaton, q: int, max_length: int) -> tuple[list[_Path], bool]:
    """Paths from q up to max_length transitions. If that search exceeds the budget, the search
    is repeated with half the depth cap; if that one fits, every path up to that length is
    listed, otherwise the paths the first search found before the budget ran out."""
    search = _Search(aut, max_length, SEARCH_BUDGET)
    paths = search.dfs(q, [], {}, None)
    if search.calls < SEARCH_BUDGET:
        return paths, True
    shallow = _Search(aut, max_length // 2, SEARCH_BUDGET)
    found = shallow.dfs(q, [], {}, None)
    return (found if shallow.calls < SEARCH_BUDGET else paths), False


def _to_sequence(path: _Path, num_loops: int) -> list[tuple[_Transition, frozenset]]:
    steps = [(t, frozenset().union(*(a.symbols for a in avoid))) for t, avoid in path.steps]
    return steps[: path.loop_index] + steps[path.loop_index :] * num_loops


def candidate_sequences(aut: Automaton, max_sequences: int, max_length: int) -> Sequences:
    """DeepLTL's candidate reach-avoid sequences from every live state, as padded arrays.

    Sequences longer than `max_length` are dropped and, past `max_sequences` per state, only
    the shortest are kept (stable order); both are reported with a warning.
    """
    num_loops = 0 if aut.is_finite else NUM_LOOPS_INFINITE
    per_state, dropped, cut = [], 0, 0
    for q in range(aut.num_states):
        if aut.violation[q] or (aut.is_finite and aut.success[q]):
            per_state.append([])
            continue
        paths, complete = _search_within_budget(aut, q, max_length)
        seqs = [_to_sequence(p, num_loops) for p in paths]
        cut += not complete
        kept = sorted((s for s in seqs if 0 < len(s) <= max_length), key=len)[:max_sequences]
        dropped += len(seqs) - len(kept)
        per_state.append(kept)
    if cut:
        warnings.warn(f"candidate search over {SEARCH_BUDGET} steps at {cut} states; their "
                      "candidate lists are incomplete (see docs/automata.md)", stacklevel=3)
    if dropped:
        warnings.warn(f"{dropped} candidate sequences dropped (over max_length={max_length} "
                      f"or max_sequences={max_sequences} per state)", stacklevel=3)
    num_seq = max(1, max(len(s) for s in per_state))
    length = max(1, max((len(x) for s in per_state for x in s), default=1))
    shape = (aut.num_states, num_seq, length)
    reach = np.zeros(shape + (aut.delta.shape[1],), dtype=bool)
    avoid = np.zeros_like(reach)
    slot = np.full(shape, -1, dtype=np.int32)
    lengths = np.zeros(shape[:2], dtype=np.int32)
    for q, seqs in enumerate(per_state):
        for c, seq in enumerate(seqs):
            lengths[q, c] = len(seq)
            for i, (t, avoid_syms) in enumerate(seq):
                reach[q, c, i, sorted(t.symbols)] = True
                avoid[q, c, i, sorted(avoid_syms)] = True
                slot[q, c, i] = t.slot
    return Sequences(reach=reach, avoid=avoid, epsilon=slot >= 0, epsilon_slot=slot,
                     length=lengths, valid=lengths > 0)
