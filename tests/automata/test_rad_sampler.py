"""RAD DFAs: canonical minimisation, the sampler's statistics against the original's
description, bank padding, and DFA tracking against the automaton step of our compiled specs."""

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax import automata, specs
from specrl_jax.automata import rad_sampler as rad
from specrl_jax.tasks import AutomatonSource
from specrl_jax.tasks.dfa_source import DFASource

LETTERS = automata.zero_or_one(12)  # 13 symbols: row 0 empty, row i letter i - 1


def _dfa(delta, accepting, start=0):
    return rad.DFA(np.asarray(delta), np.asarray(accepting, bool), start)


# over all subsets of {a, b} (symbols: {}, a, b, ab): a leads on, b fails, then ab accepts
HAND = _dfa([[0, 1, 3, 0], [1, 1, 3, 2], [2, 2, 2, 2], [3, 3, 3, 3]], [0, 0, 1, 0])


def test_minimise_merges_equivalent_states_and_numbers_canonically():
    # states 1 and 4 are equivalent, 5 is unreachable; the start is state 2 of the input
    delta = [[1, 4, 2, 0], [1, 1, 3, 1], [0, 4, 1, 2], [3, 3, 3, 3], [4, 4, 3, 4], [5, 5, 5, 5]]
    dfa = _dfa(delta, [0, 0, 0, 1, 0, 1], start=2)
    small, state_map = rad.minimise(dfa)
    assert small.num_states == 4
    assert state_map[5] == -1 and state_map[1] == state_map[4] and state_map[2] == 0
    for s in range(5):  # the map commutes with the transitions
        for a in range(4):
            assert small.delta[state_map[s], a] == state_map[delta[s][a]]
    # any renumbering of the states gives the same canonical arrays
    rng = np.random.default_rng(0)
    for _ in range(5):
        perm = rng.permutation(HAND.num_states)  # old -> new
        inv = np.argsort(perm)
        renamed = _dfa(perm[HAND.delta[inv]], HAND.accepting[inv], int(perm[0]))
        got = rad.minimise(renamed)[0]
        want = rad.minimise(HAND)[0]
        assert np.array_equal(got.delta, want.delta) and np.array_equal(got.accepting,
                                                                       want.accepting)


def test_reach_avoid_chain_follows_the_originals_distribution():
    rng = np.random.default_rng(1)
    tokens = rad.tokens_of(LETTERS)
    chains, moved = [], []
    for _ in range(3000):
        dfa = rad.sample_reach_avoid(rng, tokens, 13)
        chain = dfa.num_states - 2  # chain states never merge: each is a step further from success
        chains.append(chain)
        assert dfa.accepting.sum() == 1 and np.all(dfa.delta[:, 0] == np.arange(dfa.num_states))
        sinks = np.all(dfa.delta == np.arange(dfa.num_states)[:, None], axis=1)
        assert sinks.sum() == 2  # success and fail; the chain states all lead somewhere
        for s in np.flatnonzero(~sinks):
            moved.append(int((dfa.delta[s, tokens] != s).sum()))
    counts = np.bincount(chains, minlength=9)[1:]
    want = 0.5 ** np.arange(1, 9) / (0.5 ** np.arange(1, 9)).sum()
    np.testing.assert_allclose(counts / len(chains), want, atol=0.03)
    # per chain state: one good, one bad token, each of the other 10 leaves with probability 0.1
    assert abs(np.mean(moved) - (2 + 10 * 0.1)) < 0.1


def test_rad_conjunctions_counts_mutations_and_emptiness():
    rng = np.random.default_rng(2)
    samples = [rad.sample_rad_cdfa(rng, LETTERS) for _ in range(600)]
    counts = collections.Counter(len(c) for c in samples)
    p = 0.5 ** np.arange(1, 6) / (0.5 ** np.arange(1, 6)).sum()
    got = np.array([counts[n] for n in range(1, 6)]) / len(samples)
    assert np.abs(got - p).max() < 0.06, got  # rejection of empty conjunctions shifts a little
    for cdfa in samples:
        assert not rad.product_is_empty(cdfa)
        for dfa in cdfa:
            assert 2 <= dfa.num_states <= 10
            again = rad.minimise(dfa)[0]
            assert np.array_equal(again.delta, dfa.delta)  # stored minimal and canonical
            for s in np.flatnonzero(dfa.accepting):  # accepting states are sinks
                assert np.all(dfa.delta[s] == s)
            assert np.all(dfa.delta[:, 0] == np.arange(dfa.num_states))  # empty symbol: no-op
    # mutations leave DFAs other than chains: some state with a transition back or sideways
    non_chain = sum(any(dfa.delta[s, a] not in (s, s + 1) and not dfa.accepting[dfa.delta[s, a]]
                        and rad.live_states(dfa)[dfa.delta[s, a]]
                        for s in range(dfa.num_states) for a in range(13))
                    for c in samples for dfa in c)
    assert non_chain > 50
    # a conjunction that no word satisfies: "a before b" and "b before a", strictly
    a_first = _dfa([[0, 1, 2, 0], [1, 1, 1, 1], [2, 2, 2, 2], [3, 3, 3, 3]], [0, 1, 0, 0])
    b_first = _dfa([[0, 2, 1, 0], [1, 1, 1, 1], [2, 2, 2, 2], [3, 3, 3, 3]], [0, 1, 0, 0])
    assert rad.product_is_empty([a_first, b_first]) and not rad.product_is_empty([a_first])


def test_bank_pads_and_tracks_conjunctions():
    cdfa = [HAND, _dfa([[0, 0, 0, 1], [1, 1, 1, 1]], [0, 1])]
    bank = rad.build_bank([cdfa, [HAND]], automata.all_subsets(2), max_conjuncts=3,
                          max_states=6)
    assert bank.delta.shape == (2, 3, 6, 4)
    q = jnp.zeros(3, jnp.int32)
    for symbol, want in ((1, (False, False)), (0, (False, False)), (3, (True, False))):
        q = rad.advance(bank, 0, q, symbol)
        assert tuple(map(bool, rad.status(bank, 0, q))) == want
    assert np.array_equal(q, [3, 1, 0])  # breadth-first numbering: fail 2, accept 3
    q = rad.advance(bank, 1, jnp.zeros(3, jnp.int32), 2)  # 'b' first: HAND fails
    assert tuple(map(bool, rad.status(bank, 1, q))) == (False, True)


def test_dfa_source_tracks_the_automaton_step_of_compiled_specs():
    """The DFAs of compiled co-safe specs, stepped by the DFA source, agree with the automaton
    source on every step: DFA state = the minimisation's image of the automaton state, success
    and violation equal."""
    formulas = specs.suite("letter/finite/ind")[:3] + ["F(a & X b)", "!a U (b | c)"]
    props = tuple("abcdefghijkl")
    compiled = automata.stack([automata.compile_spec(f, props, alphabet=LETTERS)
                               for f in formulas])
    bank, state_map = rad.bank_of_specs(compiled)
    auto, dfa = AutomatonSource(compiled, LETTERS), DFASource(bank, LETTERS)
    assert int(bank.num_states.max()) <= compiled.delta.shape[1]

    def run(index, symbols):
        def body(carry, symbol):
            a, d = carry
            a, ea = auto.step(None, a, jnp.asarray(LETTERS)[symbol], symbol, False, -1)
            d, ed = dfa.step(None, d, jnp.asarray(LETTERS)[symbol], symbol, False, -1)
            return (a, d), (a.q, d.q[0], ea.success, ed.success, ea.violation, ed.violation)

        start = (auto.reset(None, None, index), dfa.reset(None, None, index))
        return jax.lax.scan(body, start, symbols)[1]

    rng = np.random.default_rng(3)
    index = np.repeat(np.arange(len(formulas)), 40)
    # symbols biased towards the formulas' letters so that episodes succeed and fail
    symbols = rng.choice(13, size=(index.size, 12), p=np.r_[0.1, [0.2] * 3, [0.3 / 9] * 9])
    aq, dq, a_ok, d_ok, a_bad, d_bad = jax.vmap(run)(jnp.asarray(index), jnp.asarray(symbols))
    np.testing.assert_array_equal(np.asarray(dq), state_map[index[:, None], np.asarray(aq)])
    np.testing.assert_array_equal(a_ok, d_ok)
    np.testing.assert_array_equal(a_bad, d_bad)
    assert np.asarray(a_ok).any() and np.asarray(a_bad).any()


def test_non_co_safe_specs_are_refused():
    spec = automata.compile_spec("G F a", ("a", "b"))
    with pytest.raises(ValueError, match="not co-safe"):
        rad.dfa_of_spec(spec)
    with pytest.raises(ValueError, match="spec 1 of the bank"):
        rad.bank_of_specs(automata.stack([automata.compile_spec("F a", ("a", "b")), spec]))
    with pytest.raises(ValueError, match="alphabet"):
        DFASource(rad.sample_bank(2, automata.zero_or_one(2)), automata.all_subsets(2))
