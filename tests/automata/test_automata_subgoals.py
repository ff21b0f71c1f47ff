"""Subgoals: DeepLTL's candidate sequences reproduce the reference's examples; one-step goals."""

import warnings

import numpy as np

from specrl_jax.automata import compile_spec, pairs, zero_or_one

ZONES = ("blue", "green", "magenta", "yellow")
NAMES = ("{}",) + ZONES


def _sequences(spec, q):
    """Candidate sequences of state q as [(reach names | 'EPS', avoid names), ...]."""
    out = []
    for c in np.nonzero(np.asarray(spec.seq_valid[q]))[0]:
        seq = []
        steps = pairs(spec, np.asarray(spec.seq_pair[q, c]))
        for i in range(int(spec.seq_length[q, c])):
            reach = ("EPS" if bool(steps.epsilon[i]) else
                     {NAMES[a] for a in np.nonzero(np.asarray(steps.reach[i]))[0]})
            avoid = {NAMES[a] for a in np.nonzero(np.asarray(steps.avoid[i]))[0]}
            seq.append((reach, avoid))
        out.append(seq)
    return out


def _canonical(seq):
    """A sequence as text with sets sorted (set order follows string hashing, which varies)."""
    return str([(r if r == "EPS" else sorted(r), sorted(a)) for r, a in seq])


def test_reference_examples():
    cases = {
        "(F blue) & (!blue U (green & F yellow))": [
            [({"green"}, {"blue"}), ({"blue"}, set()), ({"yellow"}, set())],
            [({"green"}, {"blue"}), ({"yellow"}, set()), ({"blue"}, set())],
        ],
        "!green U ((blue | magenta) & (!green U yellow))": [
            [({"blue", "magenta"}, {"green"}), ({"yellow"}, {"green"})],
        ],
        "GF blue & GF green": [[({"green"}, set()), ({"blue"}, set())] * 2],
        "FG blue": [[("EPS", set())] + [({"blue"}, {"{}", "green", "magenta", "yellow"})] * 2],
    }
    for formula, expected in cases.items():
        spec = compile_spec(formula, ZONES, zero_or_one(4))
        got = _sequences(spec, int(spec.init))
        assert sorted(map(_canonical, got)) == sorted(map(_canonical, expected)), formula


def test_epsilon_steps_name_their_slot():
    spec = compile_spec("FG blue & F (yellow & F green)", ZONES, zero_or_one(4))
    steps = pairs(spec, np.asarray(spec.seq_pair))
    eps, slot = np.asarray(steps.epsilon), np.asarray(steps.epsilon_slot)
    assert eps.any() and (slot[eps] >= 0).all() and (slot[~eps] == -1).all()
    assert not np.asarray(steps.reach)[eps].any()


def test_one_step_subgoals():
    spec = compile_spec("!green U ((blue | magenta) & (!green U yellow))", ZONES, zero_or_one(4))
    q = int(spec.init)
    valid = np.asarray(spec.subgoal_valid[q])
    assert valid.sum() == 1
    g = int(np.argmax(valid))
    reach = np.asarray(spec.subgoal_reach[q, g])
    avoid = np.asarray(spec.subgoal_avoid[q, g])
    assert reach.tolist() == [False, True, False, True, False]  # blue or magenta
    assert avoid.tolist() == [False, False, True, False, False]  # green
    target = int(spec.subgoal_target[q, g])
    assert int(spec.delta[q, 1]) == target and not bool(spec.violation[target])
    # the accepting self-loop of FG's accepting part is its subgoal
    fg = compile_spec("FG blue", ZONES, zero_or_one(4))
    q1 = int(fg.epsilon[fg.init, 0])
    assert int(fg.subgoal_target[q1, 0]) == q1 and bool(fg.subgoal_reach[q1, 0, 1])
    assert np.asarray(fg.subgoal_avoid[q1, 0]).tolist() == [True, False, True, True, True]


def test_caps_truncate_with_a_warning():
    formula = "(F blue) & (!blue U (green & F yellow))"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = compile_spec(formula, ZONES, zero_or_one(4), max_sequences=1, use_cache=False)
    assert spec.seq_valid.shape[1] == 1
    assert any("dropped" in str(w.message) for w in caught)
