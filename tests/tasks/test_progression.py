"""LTL progression tables (tasks/progression.py) against Spot's semantics on lasso words, the
padded syntax-tree graphs, the budgets, and the progression source inside the task loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import spot

from specrl_jax import automata
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.specs import ltl2action_sampler
from specrl_jax.tasks import TaskEnv
from specrl_jax.tasks.progression import (
    EDGE_ARG,
    EDGE_ARG1,
    EDGE_ARG2,
    FALSE_TOKEN,
    OPERATORS,
    PROP_OFFSET,
    ProgressionSource,
    build_bank,
    closure,
    formula_graph,
    step_state,
)

PROPS = ("a", "b", "c", "d")
FORMULAS = [
    "F(a & F(b | c))",
    "!a U (b & (!c U d))",
    "(F a) & (!b U c)",
    "G !a & F b",
    "X b | (a W c)",
    "(c R d) & F a",
    "GF a & GF b",
    "F G c",
    "a -> X(b M c)",
]


def _word_text(rows: np.ndarray) -> str:
    return " & ".join(p if on else f"!{p}" for p, on in zip(PROPS, rows))


def _satisfies(formula: spot.formula, prefix: list[np.ndarray], cycle: list[np.ndarray]) -> bool:
    """Spot's verdict: the lasso word prefix cycle^omega satisfies `formula`."""
    loop = "cycle{" + "; ".join(_word_text(r) for r in cycle) + "}"
    parts = [_word_text(r) for r in prefix] + [loop]
    word = spot.parse_word("; ".join(parts)).as_automaton()
    return spot.translate(formula).intersects(word)


@pytest.mark.parametrize("alphabet_name", ["zero_or_one", "all_subsets"])
def test_progression_invariant_matches_spot_on_random_lasso_words(alphabet_name):
    """w |= f  <=>  w[i:] |= prog(f, w[0..i-1]) at every position i of the lasso (Spot decides
    both sides); true/false states agree with Spot's verdict on the whole word."""
    alphabet = getattr(automata, alphabet_name)(len(PROPS))
    bank, states = closure(FORMULAS, PROPS, alphabet)
    rng = np.random.default_rng(0)
    for k, text in enumerate(FORMULAS):
        formula = spot.formula(text)
        for _ in range(4):
            symbols = rng.integers(0, alphabet.shape[0], size=int(rng.integers(2, 6)))
            split = int(rng.integers(0, len(symbols) - 1))
            prefix, cycle = list(symbols[:split]), list(symbols[split:])
            verdict = _satisfies(formula, [alphabet[s] for s in prefix],
                                 [alphabet[s] for s in cycle])
            word = prefix + cycle + cycle
            state = int(bank.roots[k])
            for i, symbol in enumerate(word):
                state = int(bank.delta[state, symbol])
                # the rest of the lasso from position i + 1, as a lasso again
                if i + 1 < len(prefix):
                    rest_prefix, rest_cycle = word[i + 1:len(prefix)], cycle
                else:
                    j = (i + 1 - len(prefix)) % len(cycle)
                    rest_prefix, rest_cycle = [], cycle[j:] + cycle[:j]
                got = _satisfies(states[state], [alphabet[s] for s in rest_prefix],
                                 [alphabet[s] for s in rest_cycle])
                assert got == verdict, (text, word, i, str(states[state]))
                if bank.is_true[state]:
                    assert verdict and states[state].is_tt()
                if bank.is_false[state]:
                    assert not verdict and states[state].is_ff()


def test_co_safe_training_formulas_succeed_exactly_when_spot_accepts_a_finite_word():
    """On the training distribution (co-safe), progressing to true after a finite word means
    every continuation satisfies; a word ending in the true state is accepted by Spot with any
    cycle, and a word that never reaches it is rejected with an all-false cycle."""
    letters = tuple("abcdefghijkl")
    alphabet = automata.zero_or_one(len(letters))
    rng = np.random.default_rng(1)
    formulas = [ltl2action_sampler("Eventually_1_3_1_2")(rng, letters) for _ in range(6)]
    bank = build_bank(formulas, letters, alphabet)
    for k, text in enumerate(formulas):
        aut = spot.translate(text)
        for _ in range(6):
            symbols = rng.integers(0, alphabet.shape[0], size=8)
            state = int(bank.roots[k])
            for s in symbols:
                state = int(bank.delta[state, s])
            rows = [" & ".join(p if on else f"!{p}" for p, on in zip(letters, alphabet[s]))
                    for s in symbols]
            idle = " & ".join(f"!{p}" for p in letters)
            word = spot.parse_word("; ".join(rows + ["cycle{" + idle + "}"])).as_automaton()
            assert aut.intersects(word) == bool(bank.is_true[state]), (text, symbols)
            assert not bank.is_false[state]  # reach-only: never falsified


def test_graph_is_the_original_syntax_tree_with_typed_child_to_parent_edges():
    tokens, parent, edge = formula_graph(spot.formula("!a U (b & F c)"), PROPS)
    names = ("until", "not", "and", "eventually")
    until, not_, and_, eventually = (OPERATORS.index(o) for o in names)
    a, b, c = (PROP_OFFSET + PROPS.index(p) for p in "abc")
    # preorder: U, !, a, &, b, F, c  (Spot orders the conjunction b & Fc as written)
    assert tokens == [until, not_, a, and_, b, eventually, c]
    assert parent == [-1, 0, 1, 0, 3, 3, 5]
    assert edge[1:] == [EDGE_ARG1, EDGE_ARG, EDGE_ARG2, EDGE_ARG1, EDGE_ARG2, EDGE_ARG]
    # W is drawn in the original's vocabulary; n-ary conjunctions nest to the right
    tokens, _, _ = formula_graph(spot.formula("a W b"), PROPS)
    assert OPERATORS.index("always") in tokens and OPERATORS.index("until") in tokens
    tokens, parent, _ = formula_graph(spot.formula("a & b & c"), PROPS)
    assert tokens.count(and_) == 2 and parent == [-1, 0, 0, 2, 2]


def test_bank_tables_shapes_padding_and_false_state():
    bank = build_bank(["!a U b", "F c"], PROPS, automata.zero_or_one(4))
    assert bank.delta.shape == (bank.num_states, 6) and bank.roots.shape == (2,)
    # a label outside the alphabet stays
    assert np.array_equal(np.asarray(bank.delta[:, -1]), np.arange(bank.num_states))
    falsified = int(step_state(bank, bank.roots[0], jnp.array([True, False, False, False])))
    assert bool(bank.is_false[falsified]) and int(bank.tokens[falsified, 0]) == FALSE_TOKEN
    assert np.all(np.asarray(bank.tokens[falsified, 1:]) == -1)
    done = int(step_state(bank, bank.roots[1], jnp.array([False, False, True, False])))
    assert bool(bank.is_true[done])


def test_budgets_and_bad_formulas_raise_clear_errors():
    alphabet = automata.zero_or_one(4)
    with pytest.raises(ValueError, match="max_states=3"):
        build_bank(["F(a & F(b & F(c & F d)))"], PROPS, alphabet, max_states=3)
    with pytest.raises(ValueError, match="max_nodes=4"):
        build_bank(["F(a & F(b & F c))"], PROPS, alphabet, max_nodes=4)
    with pytest.raises(ValueError, match="not among the world's propositions"):
        build_bank(["F z"], PROPS, alphabet)
    with pytest.raises(ValueError, match="at least one formula"):
        build_bank([], PROPS, alphabet)


def test_progression_source_in_the_task_loop_ends_on_truth_and_falsity():
    config = LetterConfig(grid_size=5, letters=("a", "b"), counts=1)
    world, params = make_letter_world(config, max_steps=20)
    bank = build_bank(["!b U a"], world.propositions, world.alphabet)
    task = TaskEnv(world, ProgressionSource(bank, world.alphabet))
    key = jax.random.key(0)
    _, state = task.reset(key, params)
    step = jax.jit(lambda k, s, a: task.step_task(k, s, a, params))
    outcomes = []
    for i in range(200):
        action = jax.random.randint(jax.random.fold_in(key, 5000 + i), (), 0, 4)
        _, state_next, reward, terminated, truncated, info = step(
            jax.random.fold_in(key, i), state, action)
        props = np.asarray(info["propositions"])
        if props[0]:
            assert bool(info["success"]) and float(reward) == 1.0 and bool(terminated)
            outcomes.append("success")
        elif props[1]:
            assert bool(info["violation"]) and float(reward) == -1.0 and bool(terminated)
            outcomes.append("violation")
        else:
            assert not bool(terminated)
        if bool(terminated | truncated):
            _, state_next = task.reset(jax.random.fold_in(key, 1000 + i), params)
        state = state_next
    assert "success" in outcomes and "violation" in outcomes  # the walk met both letters
