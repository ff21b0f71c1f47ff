"""DeepLTL's candidate search: the memoised search equals an independent transcription of the
reference's depth-first search (paper formulas and random automata), is complete on the paper's
Letter specs, and the compact pair table round-trips through stacking and the cache."""

import sys
import warnings
from typing import NamedTuple

import numpy as np
import pytest
from automata_paper import paper_groups

from specrl_jax.automata import cache, compile_spec, graph, pairs, stack, translate, zero_or_one
from specrl_jax.automata import candidates as sg
from specrl_jax.automata.tensors import DEFAULT_MAX_LENGTH, DEFAULT_MAX_SEQUENCES

LETTERS = tuple("abcdefghijkl")
ZONES = ("blue", "green", "magenta", "yellow")


class _Transition(NamedTuple):
    """The reference's LDBATransition over alphabet rows (symbols: the valid assignments)."""

    source: int
    target: int
    epsilon: bool
    accepting: bool
    symbols: frozenset
    slot: int

    @property
    def key(self):  # the reference's equality: (source, target, is_epsilon, accepting)
        return self.source, self.target, self.epsilon, self.accepting


class _Ldba(NamedTuple):
    out: list  # state -> its transitions (one per target and acceptance flag, then epsilon)
    scc: list  # state -> frozenset of the states of its SCC
    bottom: dict  # SCC -> no transition leaves it
    accepting: dict  # SCC -> an accepting transition has source and target in it


def _ldba(aut) -> _Ldba:
    """The reference's LDBA and SCC facts, read from the automaton's tables."""
    num_states, num_symbols = aut.delta.shape
    out = []
    for q in range(num_states):
        ts = []
        for target in sorted(set(aut.delta[q].tolist())):
            for acc in (False, True):
                syms = frozenset(a for a in range(num_symbols)
                                 if aut.delta[q, a] == target and aut.accepting[q, a] == acc)
                if syms:
                    ts.append(_Transition(q, target, False, acc, syms, -1))
        ts += [_Transition(q, int(t), True, False, frozenset(), slot)
               for slot, t in enumerate(aut.epsilon[q]) if t >= 0]
        out.append(ts)
    reach = []
    for q in range(num_states):
        seen, todo = {q}, [q]
        while todo:
            for t in out[todo.pop()]:
                if t.target not in seen:
                    seen.add(t.target)
                    todo.append(t.target)
        reach.append(seen)
    scc = [frozenset(s for s in reach[q] if q in reach[s]) for q in range(num_states)]
    bottom = {c: all(t.target in c for q in c for t in out[q]) for c in set(scc)}
    accepting = {c: any(t.accepting and t.target in c for q in c for t in out[q])
                 for c in set(scc)}
    return _Ldba(out, scc, bottom, accepting)


def _contained(path1, path2):
    """The reference's `check_path_contained` (path1 the longer)."""
    p1 = [t.symbols for t, _ in path1]
    p2 = [t.symbols for t, _ in path2]
    acc_pos = 0
    for p in p1:
        if p <= p2[acc_pos]:
            acc_pos += 1
            if acc_pos == len(p2):
                return True
    return False


def _prune(paths):
    """The reference's `prune_paths`."""
    to_remove = set()
    for i in range(len(paths)):
        for j in range(i + 1, len(paths)):
            if i in to_remove or j in to_remove:
                continue
            if len(paths[i][0]) < len(paths[j][0]):
                if _contained(paths[j][0], paths[i][0]):
                    to_remove.add(j)
            elif len(paths[i][0]) > len(paths[j][0]) and _contained(paths[i][0], paths[j][0]):
                to_remove.add(i)
            if i in to_remove:
                break
    return [p for k, p in enumerate(paths) if k not in to_remove]


def _reference_dfs(ldba, state, path, index, accepting_transition):
    """The reference's `ExhaustiveSearch.dfs` with obs=None: paths are ([(t, avoid set)], loop
    index); every simple path, pruning and avoid sets at each level."""
    index[state] = len(path)
    neg, paths = set(), []
    for t in ldba.out[state]:
        scc = ldba.scc[t.target]
        if ldba.bottom[scc] and not ldba.accepting[scc]:
            neg.add(t)
            continue
        path.append(t)
        stays_in_scc = scc == ldba.scc[t.source]
        updated = t if t.accepting and stays_in_scc else accepting_transition
        if t.target in index:
            if updated is not None and updated.key in {p.key for p in path[index[t.target]:]}:
                futures = [([], index[t.target])]
            else:
                path.pop()
                if t.source != t.target:
                    neg.add(t)
                continue
        else:
            futures = _reference_dfs(ldba, t.target, path, index, updated)
            if not futures:
                neg.add(t)
        paths += [([(t, set())] + steps, loop) for steps, loop in futures]
        path.pop()
    del index[state]
    paths = _prune(paths)
    for steps, _ in paths:
        steps[0][1].update(neg)
    return paths


def _reference_candidates(aut, q):
    """`all_sequences` at q as [((reach symbols | ("eps", slot)), avoid symbols), ...] lists,
    then as `candidate_sequences` keeps them: nonempty, shortest first (stable)."""
    num_loops = 0 if aut.is_finite else sg.NUM_LOOPS_INFINITE
    old = sys.getrecursionlimit()
    sys.setrecursionlimit(max(old, 10 * aut.num_states + 1000))
    try:
        found = _reference_dfs(_ldba(aut), q, [], {}, None)
    finally:
        sys.setrecursionlimit(old)
    seqs = []
    for steps, loop in found:
        pairs_ = [(("eps", t.slot) if t.epsilon else t.symbols,
                   frozenset().union(*(a.symbols for a in avoid))) for t, avoid in steps]
        seqs.append(pairs_[:loop] + pairs_[loop:] * num_loops)
    return sorted((s for s in seqs if s), key=len)


def _decoded(seqs: sg.Sequences, q):
    """Candidates of state q from the arrays, in the format of `_reference_candidates`."""
    out = []
    for c in np.nonzero(seqs.valid[q])[0]:
        seq = []
        for u in seqs.pair[q, c, : seqs.length[q, c]]:
            slot = int(seqs.pair_epsilon_slot[u])
            reach = ("eps", slot) if slot >= 0 else frozenset(np.nonzero(seqs.pair_reach[u])[0])
            seq.append((reach, frozenset(np.nonzero(seqs.pair_avoid[u])[0])))
        out.append(seq)
    return out


def _assert_equals_reference(aut):
    seqs = sg.candidate_sequences(aut, max_sequences=10**6, max_length=10**6)
    assert seqs.complete.all()
    for q in range(aut.num_states):
        if aut.violation[q] or (aut.is_finite and aut.success[q]):
            assert not seqs.valid[q].any()
            continue
        assert _decoded(seqs, q) == _reference_candidates(aut, q), q


@pytest.mark.parametrize("formula, props", [
    ("GF blue & GF green & G (blue -> F yellow)", ZONES),
    ("FG blue & F (yellow & F green)", ZONES),
    ("!blue U (green & (!yellow U (magenta & (!blue U yellow))))", ZONES),
    ("GF (magenta & (!blue U green)) & G !yellow", ZONES),
    ("(F blue) & (!blue U (green & F yellow))", ZONES),
    ("FG blue | GF green", ZONES),
    # a paper `rsp` spec: 27 states, one SCC of 21 (the budgeted search was incomplete here)
    ("(G F a) & G(a -> (F(b & F c) & (!d U e))) & G !(f | g | h | i)", LETTERS),
])
def test_memoised_search_equals_the_reference_dfs(formula, props):
    _assert_equals_reference(translate.translate(formula, props, zero_or_one(len(props))))


def _random_automaton(rng):
    """A random automaton cleaned as translations are (dead states merged, co-safe success
    states merged, transitions into them accepting): with epsilon edges and Buchi marks, or
    without epsilon and with an accepting absorbing state (mostly co-safe). Never empty."""
    while True:
        num_states, num_symbols = int(rng.integers(2, 10)), int(rng.integers(1, 4))
        delta = rng.integers(0, num_states, (num_states, num_symbols))
        epsilon = np.full((num_states, 2), -1)
        if rng.random() < 0.3:
            delta[-1] = num_states - 1
            accepting = np.zeros_like(delta, dtype=bool)
            accepting[-1] = True
        else:
            accepting = rng.random(delta.shape) < rng.uniform(0.05, 0.5)
            jump = rng.random(epsilon.shape) < 0.2
            epsilon[jump] = rng.integers(0, num_states, int(jump.sum()))
            epsilon[:, 1] = np.where(epsilon[:, 1] == epsilon[:, 0], -1, epsilon[:, 1])
        reach = graph.reachability(graph.adjacency(delta, epsilon))
        if graph.nonempty(delta, accepting & graph.internal(delta, reach), epsilon)[0]:
            universal = graph.dba_universal(delta, accepting)
            return translate._finalize(delta, accepting, epsilon, 0, universal, "random")


def test_memoised_search_equals_the_reference_dfs_on_random_automata():
    rng = np.random.default_rng(20261122)
    shapes = set()
    for _ in range(150):  # about 700 states in all
        aut = _random_automaton(rng)
        _assert_equals_reference(aut)
        shapes.add((aut.is_finite, bool((aut.epsilon >= 0).any()), aut.num_states > 4))
    assert len(shapes) >= 4  # co-safe and not, with and without epsilon edges, small and larger


def test_letter_paper_specs_are_complete_and_small():
    formulas, props, alphabet = paper_groups()["letter"]
    for text in formulas:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no search fallback, nothing dropped
            spec = compile_spec(text, props, alphabet, use_cache=False)
        assert np.asarray(spec.seq_complete).all()
        assert spec.nbytes < 64 * 1024, text
        assert spec.seq_pair.dtype == np.int16 and int(spec.seq_pair.max()) < len(spec.pair_reach)


def test_pairs_stack_and_padding():
    a = compile_spec("FG blue & F (yellow & F green)", ZONES, zero_or_one(4))
    b = compile_spec("F blue", ZONES, zero_or_one(4))
    stacked = stack([a, b])
    for i, spec in enumerate((a, b)):
        mine = pairs(spec, np.asarray(spec.seq_pair))
        member = pairs(jax_take(stacked, i), np.asarray(stacked.seq_pair)[i])
        s, c, length = np.asarray(spec.seq_pair).shape
        for got, want in zip(member, mine):
            got = np.asarray(got)
            assert np.array_equal(got[:s, :c, :length], np.asarray(want))
            assert not got[s:].any() if got.dtype == bool else (got[s:] == -1).all()
    assert np.asarray(stacked.seq_complete).all()
    padding = pairs(b, np.zeros((), np.int16))
    assert not padding.reach.any() and not padding.avoid.any() and int(padding.epsilon_slot) == -1


def jax_take(stacked, i):
    return type(stacked)(**{k: np.asarray(v)[i] for k, v in stacked.__dict__.items()})


def test_old_format_cache_entry_is_rebuilt(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    key = cache.cache_key("F a", ("a", "b"), zero_or_one(2),
                          max_sequences=DEFAULT_MAX_SEQUENCES, max_length=DEFAULT_MAX_LENGTH)
    fresh = compile_spec("F a", ("a", "b"), zero_or_one(2), use_cache=False)
    old = {k: np.asarray(v) for k, v in fresh.__dict__.items() if not k.startswith(("pair", "seq"))}
    old["seq_reach"] = np.zeros((3, 1, 1, 3), bool)  # the bool[S, C, L, A] layout of format 1
    cache.save(key, old)
    spec = compile_spec("F a", ("a", "b"), zero_or_one(2))
    assert np.array_equal(spec.seq_pair, fresh.seq_pair)
    assert "seq_pair" in cache.load(key)
