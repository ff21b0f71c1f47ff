"""DeepLTL's value threshold at test time against a plain-Python transcription of the original's
rule: after choosing the best path, every other non-self-loop out-transition whose best path value
is more than 0.4 below the chosen one's joins the first avoid set."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax import automata
from specrl_jax.baselines.deepltl import threshold_avoid


def reference_rule(spec, q, values, valid, threshold=0.4):
    """Plain Python over the automaton's transitions: (chosen candidate, avoided symbols)."""
    delta = np.asarray(spec.delta)
    pairs = automata.pairs(spec, spec.seq_pair[q, :, 0])
    first_reach = np.asarray(pairs.reach)
    first_eps = np.asarray(pairs.epsilon)
    candidates = [c for c in range(len(values)) if valid[c]]
    best = max(candidates, key=lambda c: values[c])
    transitions = {}  # target state -> its symbols (the original's labelled edge)
    for symbol, target in enumerate(delta[q]):
        if target != q:
            transitions.setdefault(int(target), set()).add(symbol)
    chosen = set() if first_eps[best] else set(np.flatnonzero(first_reach[best]).tolist())
    avoid = set()
    for target, symbols in transitions.items():
        if symbols & chosen:
            continue
        via = [values[c] for c in candidates
               if not first_eps[c] and set(np.flatnonzero(first_reach[c]).tolist()) & symbols]
        if via and values[best] - max(via) > threshold:
            avoid |= symbols
    return best, avoid


@pytest.mark.parametrize("formula", ["F (a & F d) | F (b & F e) | F (c & F f)",
                                     "(F (a & F b) | F c) & G !d"])
def test_threshold_matches_the_transcription(formula):
    env, _ = specrl_jax.make("LetterLTL0-v0")
    spec = automata.compile_spec(formula, env.propositions, alphabet=env.alphabet)
    q = int(spec.init)
    valid = np.asarray(spec.seq_valid[q])
    num = int(valid.sum())
    assert num >= 2  # several first transitions to choose between
    rng = np.random.default_rng(0)
    checked_augmented = False
    for values in itertools.islice((rng.random(len(valid)) for _ in range(50)), 50):
        best, expected = reference_rule(spec, q, values, valid)
        got = threshold_avoid(spec, jnp.int32(q), jnp.asarray(values, jnp.float32),
                              jnp.asarray(valid), jnp.int32(best), 0.4)
        assert set(np.flatnonzero(np.asarray(got)).tolist()) == expected
        checked_augmented |= bool(expected)
    assert checked_augmented  # some draws put a transition more than 0.4 below the best
