"""The candidate search past its limits: no recursion limit on long paths, a budget on calls and
on work with a per-state fallback to shortest paths (then to one path), flagged in
`seq_complete` and warned again on a cache hit."""

import warnings

import numpy as np
import pytest

from specrl_jax.automata import candidates as sg
from specrl_jax.automata import compile_spec, pairs, translate, zero_or_one
from specrl_jax.automata.translate import Automaton

LETTERS = tuple("abcdefghijkl")


def _candidates(spec, q):
    """[(reach symbols | ("eps", slot), avoid symbols), ...] for each candidate of state q."""
    spec = type(spec)(**{k: np.asarray(v) for k, v in spec.__dict__.items()})
    out = []
    for c in np.nonzero(spec.seq_valid[q])[0]:
        steps = pairs(spec, spec.seq_pair[q, c])
        seq = []
        for i in range(int(spec.seq_length[q, c])):
            slot = int(steps.epsilon_slot[i])
            reach = ("eps", slot) if slot >= 0 else tuple(np.nonzero(steps.reach[i])[0].tolist())
            seq.append((reach, tuple(np.nonzero(steps.avoid[i])[0].tolist())))
        out.append(seq)
    return out


def _assert_leads_to_acceptance(spec, q, seq):
    """Following seq from q: every reach symbol of a step leads to one live state and none is
    avoided; a co-safe spec ends in success, any other repeats a cycle twice that returns to
    its start through an accepting transition."""
    delta, accepting = np.asarray(spec.delta), np.asarray(spec.accepting)
    epsilon, violation = np.asarray(spec.epsilon), np.asarray(spec.violation)
    states, acc = [q], []
    for reach, avoid in seq:
        s = states[-1]
        if reach[0] == "eps":
            states.append(int(epsilon[s, reach[1]]))
            acc.append(False)
            continue
        assert len({int(delta[s, a]) for a in reach}) == 1 and not set(reach) & set(avoid)
        states.append(int(delta[s, reach[0]]))
        acc.append(bool(accepting[s, reach[0]]))
    assert not violation[states].any()
    if bool(spec.is_finite):
        assert bool(spec.success[states[-1]])
        return
    n = len(seq)
    assert any(seq[n - 2 * k: n - k] == seq[n - k:] and states[n - 2 * k] == states[n]
               and any(acc[n - k:]) for k in range(1, n // 2 + 1))


def _chain(num_states):
    """0 -b-> 1 -b-> ... -> S-2 (accepting self-loop on a), c into the dead sink S-1."""
    delta = np.tile(np.arange(num_states)[:, None], (1, 3))
    delta[: num_states - 2, 1] = np.arange(1, num_states - 1)
    delta[:, 2] = num_states - 1
    accepting = np.zeros((num_states, 3), bool)
    accepting[num_states - 2, 0] = True
    return Automaton(delta=delta.astype(np.int32), accepting=accepting,
                     epsilon=np.full((num_states, 1), -1, np.int32),
                     success=np.zeros(num_states, bool),
                     violation=np.arange(num_states) == num_states - 1, init=0, is_finite=False)


def test_a_chain_longer_than_the_recursion_limit():
    num_states = 1020  # under translate.MAX_STATES, over Python's default recursion limit
    seqs = sg.candidate_sequences(_chain(num_states), max_sequences=4, max_length=num_states)
    assert seqs.complete.all() and not seqs.dropped.any()
    reach, avoid = seqs.pair_reach[seqs.pair], seqs.pair_avoid[seqs.pair]
    for q in (0, 500, num_states - 3, num_states - 2):
        steps = num_states - 2 - q  # along the chain, then the accepting loop twice
        assert seqs.valid[q].tolist() == [True] and seqs.length[q, 0] == steps + 2
        assert (reach[q, 0, :steps].argmax(-1) == 1).all()
        assert (reach[q, 0, steps: steps + 2].argmax(-1) == 0).all()
        assert avoid[q, 0, : steps + 2].tolist() == [[False, False, True]] * (steps + 2)
    capped = sg.candidate_sequences(_chain(num_states), max_sequences=4, max_length=24)
    assert capped.valid.sum() == 23 and capped.dropped.sum() == num_states - 1 - 23


def _f_conjunction(num_terms):
    return " & ".join(f"F {c}" for c in LETTERS[:num_terms])


def test_many_eventualities_fall_back_per_state_and_warn_again_from_the_cache(
        monkeypatch, tmp_path):
    formula = _f_conjunction(7)  # 128 states, 7! paths from the initial state
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".* candidate sequences dropped")  # 7! orders, 64 kept
        complete = compile_spec(formula, LETTERS, zero_or_one(12), use_cache=False)
    assert np.asarray(complete.seq_complete).all()
    monkeypatch.setattr(sg, "WORK_BUDGET", 40_000)  # read when a search starts
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    caught = []
    for _ in range(2):  # built, then loaded from the cache
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            spec = compile_spec(formula, LETTERS, zero_or_one(12))
        caught.append(sorted(str(x.message) for x in w))
    assert caught[0] == caught[1] and any("over its budget" in m for m in caught[0])
    flags = np.asarray(spec.seq_complete)
    assert not flags[int(spec.init)] and flags.sum() > 64 and not flags.all()
    counts = np.asarray(spec.seq_valid).sum(1)
    assert counts[~flags].max() > 1  # some served by the shortest-path search, not one walk
    for q in range(spec.num_states):
        seqs, full = _candidates(spec, q), _candidates(complete, q)
        if flags[q]:
            assert seqs == full
            continue
        assert seqs and len(seqs) <= 64
        for seq in seqs:  # a shortest way: the letters still missing, each once
            assert len(seq) == len(full[0])
            _assert_leads_to_acceptance(spec, q, seq)


def test_the_last_resort_is_one_walk_into_an_accepting_cycle(monkeypatch):
    monkeypatch.setattr(sg, "SEARCH_BUDGET", 0)  # both searches fail at their first call
    for formula, props in [("FG blue & F (yellow & F green)", ("blue", "green", "magenta", "yellow")),
                           ("(G F a) & G(a -> (F(b & F c) & (!d U e))) & G !(f | g | h | i)",
                            LETTERS),
                           ("!a U (b & (!c U (d & F e)))", LETTERS)]:
        with pytest.warns(UserWarning, match="over its budget"):
            spec = compile_spec(formula, props, zero_or_one(len(props)), use_cache=False)
        live = ~np.asarray(spec.violation) & ~(np.asarray(spec.success) & bool(spec.is_finite))
        assert not np.asarray(spec.seq_complete)[live].any()
        for q in np.nonzero(live)[0]:
            (seq,) = _candidates(spec, q)
            _assert_leads_to_acceptance(spec, q, seq)


def test_long_grid_cell_compiles_through_the_shortest_path_search():
    formula = "!a U (b & (!c U (d & (!e U (f & (!g U (h & (!i U (j & (!k U l))))))))))"
    with pytest.warns(UserWarning, match="shortest paths"):
        spec = compile_spec(formula, LETTERS, zero_or_one(12), use_cache=False)
    q = int(spec.init)
    assert not bool(spec.seq_complete[q]) and np.asarray(spec.seq_complete).any()
    (seq,) = _candidates(spec, q)
    assert [LETTERS[r[0] - 1] for r, _ in seq] == list("bdfhjl")


def test_search_budgets_are_read_when_a_search_starts(monkeypatch):
    aut = translate.translate(_f_conjunction(4), LETTERS, zero_or_one(12))
    monkeypatch.setattr(sg, "SEARCH_BUDGET", 3)
    with pytest.raises(sg._OverBudget):
        sg._Search(aut).paths(aut.init)
    monkeypatch.setattr(sg, "SEARCH_BUDGET", 100)
    monkeypatch.setattr(sg, "WORK_BUDGET", 10)
    with pytest.raises(sg._OverBudget):
        sg._Search(aut).paths(aut.init)
    monkeypatch.setattr(sg, "WORK_BUDGET", 1000)
    assert len(sg._Search(aut).paths(aut.init)) == 24  # 4! orders of the four letters
