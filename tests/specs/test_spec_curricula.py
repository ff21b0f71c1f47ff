"""Curricula as data, the jittable stage sampler, and stage advancement."""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from spec_spot_helpers import reach_avoid_chain

from specrl_jax import specs
from specrl_jax.specs import curricula as cur
from specrl_jax.specs.suites import COLOURS, LETTERS
from specrl_jax.tasks.sources import SequenceSource

BATCH = 400


def test_curricula_data_match_the_reference():
    letter, zone = specs.curriculum("deepltl/letter"), specs.curriculum("deepltl/zone")
    assert [s.threshold for s in letter.stages] == [0.95, 0.95, 0.95, None]
    assert letter.stages[0].samplers == (cur.AllReachAvoid(1),)
    assert letter.stages[0].temperature == 0.1
    assert letter.stages[3].samplers == (cur.ReachAvoid(3, (1, 2), (0, 3)),)
    assert [s.threshold for s in zone.stages] == [0.8, 0.95, 0.95, 0.9, 0.9, 0.9, None]
    assert [s.aggregate for s in zone.stages] == ["min"] + ["mean"] * 6
    assert zone.stages[4].samplers == (cur.ReachAvoid(1, (1, 2), (0, 2)), cur.ReachStay(30, (0, 1)))
    assert zone.stages[4].probs == (0.4, 0.6) and zone.stages[6].probs == (0.8, 0.2)
    assert zone.stages[6].samplers[1] == cur.ReachStay(60, (0, 2))
    assert (letter.max_len, zone.max_len) == (3, 3)
    genz = specs.curriculum("genz/letter")
    assert len(genz.stages) == 1 and genz.stages[0].threshold == 0.99
    assert genz.stages[0].aggregate == "min" and genz.stages[0].temperature is None
    with pytest.raises(ValueError, match="Did you mean 'deepltl/zone'"):
        specs.curriculum("deepltl/zones")
    with pytest.raises(ValueError, match="num_props"):
        specs.CurriculumSampler(zone, num_props=1)
    with pytest.raises(ValueError, match="num_avoid"):
        bad = cur.Curriculum("bad", (cur.Stage((cur.ReachAvoid(1, (1, 1), (2, 0)),)),))
        specs.CurriculumSampler(bad, num_props=4)
    with pytest.raises(ValueError, match="alone"):
        cur.Stage((cur.AllReach(1), cur.ReachStay(3, (0, 1))), (0.5, 0.5))


@functools.cache
def _zone_sampler():
    sampler = specs.CurriculumSampler(specs.curriculum("deepltl/zone"), num_props=4)
    return sampler, lambda keys, state: sampler.sample_batch(keys, state, None)


def _draw(stage, seed=0, task_success=None):
    sampler, sample = _zone_sampler()
    state = sampler.init().replace(stage=jnp.int32(stage))
    if task_success is not None:
        state = state.replace(
            task_success=state.task_success.at[: len(task_success)].set(task_success)
        )
    keys = jax.random.split(jax.random.key(seed), BATCH)
    return jax.device_get(sample(keys, state))


def _check_rules(s):
    reach, avoid = s.reach, s.avoid
    assert not (reach & avoid).any()
    assert not (reach[:, 1:] & reach[:, :-1] & ~s.epsilon[:, :-1, None]).any()
    assert not (avoid[:, 1:] & reach[:, :-1]).any()
    for b in range(reach.shape[0]):
        assert not reach[b, s.length[b] :].any() and not avoid[b, s.length[b] :].any()


def test_enumerated_stages_draw_their_tasks():
    sampler, _ = _zone_sampler()
    assert sampler.num_slots == 72
    for stage, num_tasks, depth, has_avoid in [
        (0, 4, 1, False),
        (1, 12, 2, False),
        (3, 72, 2, True),
    ]:
        s, task = _draw(stage)
        assert ((task >= 0) & (task < num_tasks)).all() and len(set(task)) > num_tasks // 2
        assert (s.length == depth).all() and (s.repeat_last == 0).all() and not s.epsilon.any()
        tasks = jax.device_get(sampler.tasks[stage])
        assert (s.reach == tasks.reach[task]).all() and (s.avoid == tasks.avoid[task]).all()
        assert s.avoid[:, :depth].any(-1).all() == has_avoid
        _check_rules(s)


def test_explicit_stage_prefers_unsolved_tasks():
    # softmax(-success / 0.5): the solved task is drawn e^-2 as often as the others.
    _, task = _draw(0, seed=1, task_success=jnp.asarray([0.0, 0.0, 0.0, 1.0]))
    probs = np.exp(-np.asarray([0.0, 0.0, 0.0, 1.0]) / 0.5)
    counts = np.bincount(task, minlength=4)
    assert stats.chisquare(counts, probs / probs.sum() * counts.sum()).pvalue > 1e-3


@pytest.mark.parametrize("stage, stay_prob, repeat, depth", [(4, 0.6, 30, 1), (6, 0.2, 60, 3)])
def test_mixture_stages(stage, stay_prob, repeat, depth):
    s, task = _draw(stage)
    assert (task == -1).all()
    stay = s.epsilon[:, 0]
    assert abs(stay.mean() - stay_prob) < 0.08
    assert (s.repeat_last[stay] == repeat).all() and (s.length[stay] == 2).all()
    assert s.avoid_empty[stay, 1].all() and not s.avoid_empty[~stay].any()
    assert (s.length[~stay] == depth).all() and (s.repeat_last[~stay] == 0).all()
    _check_rules(s)
    for i in range(0, BATCH, 10):
        one = jax.tree_util.tree_map(lambda x, i=i: x[i], s)
        text = specs.sequence_to_formula(one, COLOURS)
        assert specs.is_satisfiable(text, COLOURS), text


def _episodes(task_ids, successes, finished=None):
    task_ids = jnp.asarray(task_ids, jnp.int32)
    finished = jnp.ones(task_ids.shape, bool) if finished is None else jnp.asarray(finished)
    return task_ids, finished, jnp.asarray(successes, bool)


def test_update_min_stage_advances_only_when_every_task_passes():
    sampler, _ = _zone_sampler()
    update = jax.jit(sampler.update)
    state = sampler.init()
    # Task rates: 0 -> 1.0, 1 -> 0.75 (4 episodes), 2 and 3 -> 1.0: min 0.75 < 0.8.
    ids = [0, 1, 1, 1, 1, 2, 3]
    held = update(state, *_episodes(ids, [1, 1, 1, 1, 0, 1, 1]))
    assert int(held.stage) == 0
    np.testing.assert_allclose(held.task_success[:4], [1.0, 0.75, 1.0, 1.0])
    # An unfinished failure does not count: min is now 1.0.
    moved = update(state, *_episodes(ids, [1, 1, 1, 1, 0, 1, 1], [1, 1, 1, 1, 0, 1, 1]))
    assert int(moved.stage) == 1 and not moved.task_success.any() and not bool(moved.finished)
    # Nothing finished: nothing changes.
    idle = update(held, *_episodes(ids, [1] * 7, [0] * 7))
    assert int(idle.stage) == 0 and (idle.task_success == held.task_success).all()


def test_update_mean_stages_and_sampled_episodes():
    sampler, _ = _zone_sampler()
    update = jax.jit(sampler.update)
    at = lambda stage: sampler.init().replace(stage=jnp.int32(stage))
    # Stage 1 (mean >= 0.95) averages tasks, not episodes: rates 1.0 and 0.9 give 0.95
    # (the per-episode mean, 10/11, would fail).
    moved = update(at(1), *_episodes([0] + [5] * 10, [1] + [1] * 9 + [0]))
    assert int(moved.stage) == 2
    held = update(at(1), *_episodes([0] + [5] * 10, [1] + [1] * 8 + [0] * 2))
    assert int(held.stage) == 1
    # Sampled stage 4 (mean >= 0.9): each episode is its own task.
    assert int(update(at(4), *_episodes([-1] * 10, [1] * 9 + [0])).stage) == 5
    assert int(update(at(4), *_episodes([-1] * 10, [1] * 8 + [0] * 2)).stage) == 4
    # The final stage has no threshold.
    last = update(at(6), *_episodes([-1] * 10, [1] * 10))
    assert int(last.stage) == 6 and not bool(last.finished)


def test_genz_curriculum_finishes_and_respects_the_current_assignment():
    sampler = specs.CurriculumSampler(specs.curriculum("genz/zone"), num_props=4)
    assert sampler.num_slots == 32 and sampler.max_len == 1
    current = jnp.zeros((BATCH, 4), bool).at[:, 1].set(True)
    sample = jax.jit(jax.vmap(sampler.sample, in_axes=(0, None, 0)))
    s, task = jax.device_get(
        sample(jax.random.split(jax.random.key(2), BATCH), sampler.init(), current)
    )
    assert (task >= 0).all() and not s.reach[:, 0, 1].any() and not s.avoid[:, 0, 1].any()
    update = jax.jit(sampler.update)
    all_tasks = jnp.arange(32)
    done = update(sampler.init(), *_episodes(all_tasks, [1] * 32))
    assert bool(done.finished) and int(done.stage) == 0
    not_done = update(sampler.init(), *_episodes(all_tasks, [1] * 31 + [0]))
    assert not bool(not_done.finished)


def test_letter_curriculum_formulas_are_satisfiable_and_deterministic():
    sampler = specs.CurriculumSampler(specs.curriculum("deepltl/letter"), num_props=12)
    assert sampler.num_slots == 132
    for stage, depth in enumerate([1, 1, 2, 3]):
        texts = sampler.sample_formulas(seed=stage, stage=stage, num=40, propositions=LETTERS)
        assert texts == sampler.sample_formulas(stage, stage, 40, LETTERS)
        for text in texts:
            assert specs.is_satisfiable(text, LETTERS), text
            pairs = reach_avoid_chain(text)
            assert len(pairs) == depth and all(not r & a for r, a in pairs), text
    with pytest.raises(ValueError, match="propositions"):
        sampler.sample_formulas(0, 0, 2, COLOURS)


def test_longer_stays_scale_every_reach_stay_task_and_nothing_else():
    longer = specs.with_stay(cur.DEEPLTL_ZONE, 600)
    assert longer.name == "deepltl/zone+stay600"
    for old, new in zip(cur.DEEPLTL_ZONE.stages, longer.stages, strict=True):
        assert (new.probs, new.threshold, new.aggregate, new.temperature) == (
            old.probs, old.threshold, old.aggregate, old.temperature)
        for a, b in zip(old.samplers, new.samplers, strict=True):
            if isinstance(a, cur.ReachStay):
                assert (b.num_stay, b.num_avoid) == (a.num_stay * 10, a.num_avoid)
            else:
                assert a == b
    sampler = cur.CurriculumSampler(longer, len(COLOURS))
    state = sampler.init().replace(stage=jnp.int32(4))
    s, _ = jax.device_get(sampler.sample_batch(jax.random.split(jax.random.key(0), 64), state, None))
    stay = s.epsilon[:, 0]
    assert stay.any() and (s.repeat_last[stay] == 300).all()
    assert specs.with_stay(cur.DEEPLTL_ZONE, np.int64(600)) == longer
    for bad in (0, -5, 2.5, True):
        with pytest.raises(ValueError, match="positive number of steps"):
            specs.with_stay(cur.DEEPLTL_ZONE, bad)
    with pytest.raises(ValueError, match="no reach-stay tasks"):
        specs.with_stay(cur.DEEPLTL_LETTER, 100)


def test_twins_stay_out_of_every_avoid_set():
    """With same-object twins (props 0/1 and 2/3 name one sphere each, as the grippers-and-arm
    Arm's `arm_c` / `grippers_c`), no avoid set of any stage holds a twin of its reach or of
    the previous reach, the stay pair of a reach-stay task leaves the stay's twin allowed, and
    the enumerated reach-avoid stages lose the twin pairs (12 tasks -> 8, 72 -> 16); without
    twins the same draws do pair a reach with its twin."""
    twins = specs.twin_matrix(["a0", "a1", "b0", "b1"], [("a0", "a1"), ("b0", "b1")])
    assert (twins == twins.T).all() and twins.sum() == 4 and not twins.diagonal().any()
    with pytest.raises(ValueError, match="need two of"):
        specs.twin_matrix(["a0", "a1"], [("a0", "c")])
    with pytest.raises(ValueError, match=r"twins must be a symmetric bool\[4, 4\]"):
        specs.CurriculumSampler(specs.curriculum("deepltl/zone"), 4, twins=np.eye(3, dtype=bool))
    sampler = specs.CurriculumSampler(specs.curriculum("deepltl/zone"), 4, twins=twins)
    assert [cur._num_tasks(t) for t in sampler.tasks if t is not None] == [4, 12, 8, 16]
    sample = jax.jit(jax.vmap(sampler.sample, in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(3), BATCH)
    for stage in range(len(sampler.curriculum.stages)):
        s, _ = jax.device_get(sample(keys, sampler.init().replace(stage=jnp.int32(stage))))
        reach, avoid = np.asarray(s.reach), np.asarray(s.avoid)
        twin_of = (reach[..., :, None] & twins).any(-2)  # [B, L, P]
        assert not (avoid & twin_of).any(), stage
        assert not (avoid[:, 1:] & twin_of[:, :-1] & ~s.epsilon[:, :-1, None]).any(), stage
        _check_rules(s)
        if stage >= 4:  # mixtures with reach-stay tasks: the stay pair avoids the two others
            stays = np.asarray(s.epsilon[:, 0])
            assert stays.any() and (avoid[stays, 1].sum(-1) == 2).all()
            assert not (avoid[stays, 0] & twin_of[stays, 1]).any()
    # a task from a stay pair: every assignment without the stay proposition violates it (the
    # twin alone too), and so does any other proposition; the stay with its twin does not
    alphabet = np.array(list(itertools.product([False, True], repeat=4)))
    source = SequenceSource(sampler, jnp.asarray(alphabet))
    stays = np.flatnonzero(np.asarray(s.epsilon[:, 0]))[:8]
    for b in stays:
        task = source.from_sequence(jax.tree_util.tree_map(lambda x, b=b: x[b], s))
        stay = int(np.argmax(s.reach[b, 1]))
        others = ~(np.arange(4) == stay) & ~twins[stay]
        expected = ~alphabet[:, stay] | alphabet[:, others].any(1)
        np.testing.assert_array_equal(np.asarray(task.avoid[1]), expected)
        both = alphabet[:, stay] & alphabet[:, twins[stay]].all(1) & ~alphabet[:, others].any(1)
        assert both.sum() == 1 and not expected[both].any()
    plain = specs.CurriculumSampler(specs.curriculum("deepltl/zone"), 4)
    s, _ = jax.device_get(jax.vmap(plain.sample, in_axes=(0, None))(
        keys, plain.init().replace(stage=jnp.int32(5))))
    assert (np.asarray(s.avoid) & (np.asarray(s.reach)[..., :, None] & twins).any(-2)).any()
    for b in np.flatnonzero(np.asarray(s.epsilon[:, 0]))[:8]:  # without twins: the avoid set
        task = SequenceSource(plain, jnp.asarray(alphabet)).from_sequence(
            jax.tree_util.tree_map(lambda x, b=b: x[b], s))
        stay = int(np.argmax(s.reach[b, 1]))
        np.testing.assert_array_equal(np.asarray(task.avoid[1]), ~alphabet[:, stay] | (
            alphabet[:, np.arange(4) != stay].any(1)))
