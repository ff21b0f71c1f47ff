"""Accepting visits of LetterWorld's first response task, counted by hand per cycle, on our
automaton and on the original's LDBA:
`(G F a) & G(a -> (F(b & F c) & (!d U e))) & G !(f | g | h | i)`.

A round answers an `a` with `e` (before any `d`) and with `b` then `c`. Ours accepts once per
round, on the `e` of the round after a completed one; the original's accepts on the `c` that
completes a round (and on a first empty label). Words that alternate `a e` or `a b` forever (the
non-accepting cycles GenZ-LTL's one-subgoal choice can fall into) count nothing on either.
"""

import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, specs
from tests.eval.test_original_ldba import _count, built, world

SYMBOL = {letter: i + 1 for i, letter in enumerate("abcdefghijkl")} | {".": 0}


def _ours(word: str) -> str:
    env = world("letter/infinite/rsp")
    spec = automata.compile_spec(specs.suite("letter/infinite/rsp")[0], env.propositions,
                                 alphabet=env.alphabet)
    alphabet, q, marks = jnp.asarray(env.alphabet), spec.init, ""
    for letter in word:
        q, accepted, _, violation = automata.step(spec, q, alphabet[SYMBOL[letter]], False)
        assert not bool(violation)
        marks += "A" if bool(accepted) else "-"
    return marks


def _original(word: str) -> str:
    symbols = jnp.asarray([SYMBOL[letter] for letter in word])
    _, accepted = _count(built("letter/infinite/rsp", 0), symbols, jnp.zeros(len(word), bool),
                         "policy")
    return "".join("A" if a else "-" for a in np.asarray(accepted))


def test_one_accepting_visit_per_answered_round():
    rounds = "aebc" * 4
    assert _ours(rounds) == "-----A---A---A--"  # 4 rounds: 3 visits, at the next round's e
    assert _original(rounds) == "---A---A---A---A"  # 4 visits, at each round's c
    # the order of b / c and e within a round does not change the count
    assert _ours("abebc" * 3).count("A") == 2 and _original("abebc" * 3).count("A") == 3
    assert _ours("aecbc" * 3).count("A") == 2 and _original("aecbc" * 3).count("A") == 3


def test_rounds_never_completed_count_nothing():
    for word in ("ae" * 8, "ab" * 8, "abe" * 5):
        assert _ours(word).count("A") == 0, word
        assert _original(word).count("A") == 0, word
