"""An epsilon jump that guessed wrong: `F G a & G !(b | c)` after the jump into the loop on 'a'.
Leaving 'a' for an empty cell kills the jumped run but not the formula, so the task returns to
the run that never jumped (no violation) and may jump again; 'b' violates the formula."""

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.automata import compile_suite
from specrl_jax.tasks.sources import AutomatonSource

PROPS = ("a", "b", "c")
ALPHABET = np.concatenate([np.zeros((1, 3), bool), np.eye(3, dtype=bool)])
NONE, A, B = ALPHABET[0], ALPHABET[1], ALPHABET[2]


def _run(fall_back: bool, word):
    """Step the source on `word`: a list of labels bool[P], or "eps" for an epsilon step.
    Returns (q, progress, accepted, violation) per step."""
    specs = compile_suite(["F G a & G !(b | c)"], PROPS, ALPHABET)
    source = AutomatonSource(specs, jnp.asarray(ALPHABET), fall_back=fall_back)
    task = source.reset(jax.random.key(0), None, jnp.int32(0))
    step = jax.jit(source.step)
    out, label = [], NONE
    for item in word:
        is_eps = item == "eps" if isinstance(item, str) else False
        label = label if is_eps else item
        task, events = step(jax.random.key(1), task, jnp.asarray(label), None,
                            jnp.asarray(is_eps), jnp.int32(0))
        out.append((int(task.q), bool(events.progress), bool(events.accepted),
                    bool(events.violation)))
    return out


def test_leaving_the_goal_after_the_jump_falls_back_to_the_run_that_never_jumped():
    word = [A, "eps", A, A, NONE, NONE, A, "eps", A, B]
    steps = _run(True, word)
    init = steps[0][0]
    assert [v for *_, v in steps] == [False] * 9 + [True]
    assert [a for _, _, a, _ in steps] == [False, False, True, True, False, False, False, False,
                                           True, False]
    assert steps[4][0] == init and not steps[4][1]  # back before the jump; no progress
    assert steps[7][0] == steps[1][0]  # the second jump lands where the first did


def test_without_fall_back_leaving_the_goal_after_the_jump_is_a_violation():
    steps = _run(False, [A, "eps", A, NONE])
    assert [v for *_, v in steps] == [False, False, False, True]


def test_a_spec_without_epsilon_edges_steps_as_before():
    specs = compile_suite(["G F a & G !b"], PROPS, ALPHABET)
    for fall_back in (True, False):
        source = AutomatonSource(specs, jnp.asarray(ALPHABET), fall_back=fall_back)
        task = source.reset(jax.random.key(0), None, jnp.int32(0))
        for label in (A, NONE, A, B):
            task, events = source.step(jax.random.key(1), task, jnp.asarray(label), None,
                                       jnp.zeros((), bool), jnp.int32(-1))
            assert int(task.q) == int(task.q_free)
        assert bool(events.violation)
