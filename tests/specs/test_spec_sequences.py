"""Jittable training-sequence samplers: rules, determinism, distributions, Spot agreement."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import spot
from scipy import stats
from spec_spot_helpers import accepts

from specrl_jax import specs
from specrl_jax.specs.suites import COLOURS, LETTERS

NUM = 1500
MAX_LEN = 4


@functools.cache
def _reach_avoid_batch(num_props: int, seed: int):
    sample = functools.partial(
        specs.sample_reach_avoid_sequence,
        num_props=num_props,
        depth=3,
        num_reach=(1, 2),
        num_avoid=(0, 3),
        max_len=MAX_LEN,
    )
    keys = jax.random.split(jax.random.key(seed), NUM)
    return jax.device_get(jax.jit(jax.vmap(sample))(keys))


@pytest.mark.parametrize("num_props", [12, 4])
def test_reach_avoid_sequence_rules(num_props):
    s = _reach_avoid_batch(num_props, 0)
    reach, avoid = s.reach, s.avoid
    assert reach.shape == avoid.shape == (NUM, MAX_LEN, num_props)
    assert (s.length == 3).all() and (s.repeat_last == 0).all()
    assert not s.epsilon.any() and not s.avoid_empty.any()
    assert not reach[:, 3:].any() and not avoid[:, 3:].any()  # padding
    num_reach, num_avoid = reach[:, :3].sum(-1), avoid[:, :3].sum(-1)
    assert set(np.unique(num_reach)) == {1, 2}
    assert not (reach & avoid).any()
    assert not (reach[:, 1:3] & reach[:, :2]).any()  # consecutive reach sets disjoint
    assert not (avoid[:, 1:3] & reach[:, :2]).any()  # avoid excludes the previous reach
    free = num_props - num_reach - np.concatenate([np.zeros((NUM, 1)), num_reach[:, :2]], 1)
    assert (num_avoid <= np.minimum(3, free)).all()
    # Every avoid size 0..3 occurs where there is room for it, roughly uniformly.
    roomy = free >= 3
    counts = np.bincount(num_avoid[roomy], minlength=4)
    assert (counts > 0.2 * roomy.sum()).all()


def test_reach_avoid_sequence_is_deterministic_per_key():
    a, b = _reach_avoid_batch(12, 0), _reach_avoid_batch(12, 1)
    again = jax.device_get(
        jax.jit(
            jax.vmap(
                functools.partial(
                    specs.sample_reach_avoid_sequence,
                    num_props=12,
                    depth=3,
                    num_reach=(1, 2),
                    num_avoid=(0, 3),
                    max_len=MAX_LEN,
                )
            )
        )(jax.random.split(jax.random.key(0), NUM))
    )
    assert (a.reach == again.reach).all() and (a.avoid == again.avoid).all()
    assert (a.reach != b.reach).any()
    assert len({r.tobytes() for r in a.reach}) > 0.9 * NUM


@pytest.mark.parametrize("num_props, props", [(12, LETTERS), (4, COLOURS)])
def test_sampled_sequences_as_formulas_agree_with_spot(num_props, props):
    s = _reach_avoid_batch(num_props, 0)
    for i in range(60):
        one = jax.tree_util.tree_map(lambda x, i=i: x[i], s)
        text = specs.sequence_to_formula(one, props)
        assert specs.is_satisfiable(text, props), text
        walk = [props[int(np.flatnonzero(r)[0])] for r in one.reach[:3]]
        assert accepts(text, walk, props), text
        first_avoid = np.flatnonzero(one.avoid[0])
        if first_avoid.size:
            assert not accepts(text, [props[first_avoid[0]]] + walk, props), text


def test_reach_stay_structure_and_formula():
    sample = functools.partial(
        specs.sample_reach_stay, num_props=4, num_stay=30, num_avoid=(0, 2), max_len=3
    )
    s = jax.device_get(jax.jit(jax.vmap(sample))(jax.random.split(jax.random.key(3), 400)))
    assert (s.length == 2).all() and (s.repeat_last == 30).all()
    assert s.epsilon[:, 0].all() and not s.epsilon[:, 1:].any()
    assert s.avoid_empty[:, 1].all() and not s.avoid_empty[:, [0, 2]].any()
    assert not s.reach[:, 0].any() and (s.reach[:, 1].sum(-1) == 1).all()
    assert (s.avoid[:, 1] == ~s.reach[:, 1]).all()  # the stay pair avoids every other prop
    assert not (s.avoid[:, 0] & s.reach[:, 1]).any()
    assert set(np.unique(s.avoid[:, 0].sum(-1))) == {0, 1, 2}
    assert set(np.argmax(s.reach[:, 1], -1)) == {0, 1, 2, 3}
    for i in range(20):
        one = jax.tree_util.tree_map(lambda x, i=i: x[i], s)
        text = specs.sequence_to_formula(one, COLOURS)
        assert specs.is_satisfiable(text, COLOURS), text
        stay = COLOURS[int(np.argmax(one.reach[1]))]
        aut = spot.translate(text)
        cube = " & ".join(p if p == stay else f"!{p}" for p in COLOURS)
        assert aut.intersects(spot.parse_word(f"cycle{{{cube}}}").as_automaton())


def test_enumerations_count_and_rules():
    assert specs.all_reach_tasks(4, 1, 1).reach.shape == (4, 1, 4)
    assert specs.all_reach_tasks(4, 2, 3).reach.shape == (12, 3, 4)
    assert specs.all_reach_avoid_tasks(4, 1, 1).reach.shape[0] == 12
    assert specs.all_reach_avoid_tasks(4, 2, 2).reach.shape[0] == 72
    assert specs.all_reach_avoid_tasks(12, 1, 1).reach.shape[0] == 132
    tasks = specs.all_reach_avoid_tasks(5, 3, 4)
    assert tasks.reach.shape[0] == 5 * 4 * (4 * 3) ** 2
    reach, avoid = np.asarray(tasks.reach), np.asarray(tasks.avoid)
    assert (reach[:, :3].sum(-1) == 1).all() and (avoid[:, :3].sum(-1) == 1).all()
    assert not reach[:, 3].any() and (np.asarray(tasks.length) == 3).all()
    assert not (reach & avoid).any()
    assert not (reach[:, 1:3] & reach[:, :2]).any() and not (avoid[:, 1:3] & reach[:, :2]).any()
    assert len({(r.tobytes(), a.tobytes()) for r, a in zip(reach, avoid)}) == reach.shape[0]


def test_explicit_task_draw_follows_softmax():
    tasks = specs.all_reach_tasks(4, 1, 1)
    success = jnp.asarray([0.0, 0.5, 1.0, 0.2])
    logits = -success / 0.5
    draw = jax.jit(jax.vmap(specs.sample_task, in_axes=(0, None, None)))
    seqs, index = draw(jax.random.split(jax.random.key(4), 8000), tasks, logits)
    counts = np.bincount(np.asarray(index), minlength=4)
    probs = np.exp(-np.asarray(success, np.float64) / 0.5)
    expected = probs / probs.sum() * counts.sum()
    assert stats.chisquare(counts, expected).pvalue > 1e-3
    assert (np.argmax(np.asarray(seqs.reach[:, 0]), -1) == np.asarray(index)).all()


@pytest.mark.parametrize("num_props, num_tasks", [(12, 2784), (4, 32)])
def test_genz_subgoals_uniform_and_exclude_the_current_assignment(num_props, num_tasks):
    tasks = specs.genz_tasks(num_props)
    assert tasks.num_tasks == num_tasks
    reach, avoid = np.asarray(tasks.reach), np.asarray(tasks.avoid)
    assert not avoid[np.arange(num_tasks), reach].any() and (avoid.sum(-1) <= 3).all()
    assert len({(r, a.tobytes()) for r, a in zip(reach, avoid)}) == num_tasks
    draw = jax.jit(jax.vmap(specs.sample_genz_subgoal, in_axes=(0, None, 0)))
    num_free = 200 * num_tasks if num_props == 4 else 8 * num_tasks
    num = num_free + 4000
    current = np.zeros((num, num_props), bool)
    current[num_free:, 2] = True  # the rest stands on proposition 2
    seq, index = draw(jax.random.split(jax.random.key(5), num), tasks, jnp.asarray(current))
    index = np.asarray(index)
    assert (np.asarray(seq.length) == 1).all() and seq.reach.shape == (num, 1, num_props)
    assert (np.argmax(np.asarray(seq.reach[:, 0]), -1) == reach[index]).all()
    assert (np.asarray(seq.avoid[:, 0]) == avoid[index]).all()
    free, busy = index[:num_free], index[num_free:]
    counts = np.bincount(free, minlength=num_tasks)
    assert stats.chisquare(counts).pvalue > 1e-3
    open_tasks = (reach != 2) & ~avoid[:, 2]
    assert open_tasks[busy].all()
    # Every reach proposition other than 2 keeps the same number of open tasks: uniform reach.
    by_reach = np.bincount(reach[busy], minlength=num_props)
    assert by_reach[2] == 0
    assert stats.chisquare(np.delete(by_reach, 2)).pvalue > 1e-3


def test_bad_static_settings_raise():
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="max_len"):
        specs.sample_reach_avoid_sequence(key, 4, 3, (1, 1), (0, 1), max_len=2)
    with pytest.raises(ValueError, match="num_avoid"):
        specs.sample_reach_avoid_sequence(key, 4, 1, (1, 1), (2, 1), max_len=2)
    with pytest.raises(ValueError, match="num_reach"):
        specs.sample_reach_avoid_sequence(key, 4, 1, (0, 1), (0, 1), max_len=2)
