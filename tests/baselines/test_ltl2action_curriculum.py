"""LTL2Action on the DeepLTL curriculum (tasks/curriculum_progression.py): the formulas are the
curriculum's tasks, their progression follows the curriculum's sequence tracker and Spot, the
source draws from the current stage and advances it, and the method learns a tiny world."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import spot
from tiny_learning import early_late, train_rows

from specrl_jax import automata
from specrl_jax.baselines import ltl2action
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.specs import CurriculumSampler, curriculum
from specrl_jax.tasks import SequenceSource
from specrl_jax.tasks.curriculum_progression import (
    NEVER_TRUE,
    CurriculumProgressionSource,
    stage_formulas,
)
from specrl_jax.tasks.progression import build_bank, closure

LETTERS = tuple("abcdefghijkl")
COLOURS = ("blue", "green", "magenta", "yellow")


def _stage_sequences(sampler: CurriculumSampler, stage: int, num: int, seed: int):
    """`num` sequences of a stage, as the curriculum draws them (host arrays, leading axis)."""
    if sampler.tasks[stage] is not None:
        return jax.device_get(sampler.tasks[stage])
    keys = jax.random.split(jax.random.key(seed), num)
    state = sampler.init().replace(stage=jnp.int32(stage))
    return jax.device_get(sampler.sample_batch(keys, state, None)[0])


def _written_out(seq, k: int, props) -> str:
    """Sequence k as `!(A1) U (R1 & (!(A2) U (R2 & ...)))` (`true U` for an empty avoid), or
    `!K U G p` for a reach-stay task; written here from the arrays, independently."""
    names = np.asarray(props)
    length = int(seq.length[k])
    if seq.epsilon[k, :length].any():
        stay = names[seq.reach[k, 1]][0]
        return f"!({' | '.join(['false', *names[seq.avoid[k, 0]]])}) U G {stay}"
    text = "true"
    for i in reversed(range(length)):
        avoid = " | ".join(["false", *names[seq.avoid[k, i]]])
        reach = " | ".join(names[seq.reach[k, i]])
        text = f"!({avoid}) U (({reach}) & ({text}))"
    return text


@pytest.mark.parametrize("name,props", [("deepltl/letter", LETTERS), ("deepltl/zone", COLOURS)])
def test_stage_formulas_are_the_curriculum_tasks(name, props):
    """Every stage's formulas are Spot-equivalent to the curriculum's own tasks: all tasks of an
    enumerated stage in order, the sampler's draws (same seed) of a sampled stage."""
    sampler = CurriculumSampler(curriculum(name), len(props))
    for seed in (0, 7):
        by_stage = stage_formulas(sampler, props, per_stage=6, seed=seed)
        assert len(by_stage) == len(sampler.curriculum.stages)
        for stage, formulas in enumerate(by_stage):
            seqs = _stage_sequences(sampler, stage, 6, seed + stage)
            assert len(formulas) == len(seqs.length)
            for k in range(0, len(formulas), max(1, len(formulas) // 8)):
                assert spot.are_equivalent(spot.formula(formulas[k]),
                                           spot.formula(_written_out(seqs, k, props))), formulas[k]


def _words_by_tracker(seqs, alphabet, steps: int, key):
    """Random words steered half the time onto the tracker's current reach set: symbols
    int32[K, W, T] and the tracker's success / violation flags bool[K, W, T]."""
    alphabet = jnp.asarray(alphabet)
    source = SequenceSource(CurriculumSampler(curriculum("deepltl/letter"), alphabet.shape[1]),
                            alphabet)
    num_words = 32

    def run(seq, key):
        task = source.from_sequence(seq)

        def body(task, key):
            key_pick, key_steer = jax.random.split(key)
            reach = task.reach[task.current].astype(jnp.float32)
            uniform = jnp.full(alphabet.shape[0], 1.0 / alphabet.shape[0])
            probs = 0.5 * uniform + 0.5 * reach / jnp.maximum(reach.sum(), 1.0)
            symbol = jax.random.choice(key_pick, alphabet.shape[0], p=probs)
            task, events = source.step(key_steer, task, alphabet[symbol], symbol,
                                       jnp.zeros((), bool), jnp.int32(-1))
            return task, (symbol, events.success, events.violation)

        return jax.lax.scan(body, task, jax.random.split(key, steps))[1]

    per_word = jax.vmap(run, in_axes=(None, 0))
    per_seq = jax.vmap(lambda s, k: per_word(s, jax.random.split(k, num_words)))
    keys = jax.random.split(key, len(seqs.length))
    return jax.device_get(jax.jit(per_seq)(jax.tree.map(jnp.asarray, seqs), keys))


@pytest.mark.parametrize("name,props,stages", [("deepltl/letter", LETTERS, (1, 2, 3)),
                                               ("deepltl/zone", COLOURS, (3, 5, 6))])
def test_progression_follows_the_sequence_tracker(name, props, stages):
    """On words of one proposition at a time, against the curriculum's sequence tracker: the
    formula is true exactly when the tracker completes the sequence, unless the tracker was
    violated first; it is false only at or after a tracker violation (the formula does not
    commit to the first visit of a reach set, the tracker does)."""
    alphabet = automata.zero_or_one(len(props))
    sampler = CurriculumSampler(curriculum(name), len(props))
    by_stage = stage_formulas(sampler, props, per_stage=12, seed=3)
    completed = relaxed = 0
    for stage in stages:
        seqs = _stage_sequences(sampler, stage, 12, 3 + stage)
        plain = ~seqs.epsilon.any(axis=1)  # reach-stay tasks have no finite formula to compare
        seqs = jax.tree.map(lambda x: x[plain], seqs)
        formulas = [f for f, keep in zip(by_stage[stage], plain) if keep]
        bank = build_bank(formulas, props, alphabet)
        delta, is_true, is_false = (np.asarray(x)
                                    for x in (bank.delta, bank.is_true, bank.is_false))
        symbols, done, violated = _words_by_tracker(seqs, alphabet, 24, jax.random.key(stage))
        for k in range(len(formulas)):
            for w in range(symbols.shape[1]):
                state, seq_violated = int(bank.roots[k]), False
                for t in range(symbols.shape[2]):
                    state = delta[state, symbols[k, w, t]]
                    seq_violated |= bool(violated[k, w, t])  # the tracker's episode ends here
                    if done[k, w, t] and not seq_violated:
                        assert is_true[state], (formulas[k], symbols[k, w, : t + 1])
                        completed += 1
                    if is_true[state]:
                        assert done[k, w, t] or seq_violated, (formulas[k], symbols[k, w, : t + 1])
                        relaxed += int(seq_violated)
                    if is_false[state]:
                        assert seq_violated, (formulas[k], symbols[k, w, : t + 1])
                    if is_true[state] or is_false[state]:
                        break
    assert completed > 50 and relaxed > 0, (completed, relaxed)  # both cases were seen


def test_curriculum_bank_progression_matches_spot_on_lasso_words():
    """w |= f  <=>  w[i:] |= state after w[0..i-1], Spot deciding both, for curriculum formulas."""
    alphabet = automata.zero_or_one(len(COLOURS))
    sampler = CurriculumSampler(curriculum("deepltl/zone"), len(COLOURS))
    formulas = [f for stage in stage_formulas(sampler, COLOURS, per_stage=3, seed=1)[3:]
                for f in stage]
    bank, states = closure(formulas, COLOURS, alphabet)
    delta = np.asarray(bank.delta)
    rng = np.random.default_rng(0)

    def text(row):
        return " & ".join(p if on else f"!{p}" for p, on in zip(COLOURS, row))

    def holds(f, prefix, cycle):
        loop = "cycle{" + "; ".join(text(alphabet[s]) for s in cycle) + "}"
        word = spot.parse_word("; ".join([*(text(alphabet[s]) for s in prefix), loop]))
        return spot.translate(f).intersects(word.as_automaton())

    for k in rng.choice(len(formulas), 12, replace=False):
        word = rng.integers(0, len(alphabet), 8).tolist()
        cycle = rng.integers(0, len(alphabet), 2).tolist()
        state = int(bank.roots[k])
        verdict = holds(states[state], word, cycle)
        for i, symbol in enumerate(word):
            state = delta[state, symbol]
            assert holds(states[state], word[i + 1:], cycle) == verdict, (formulas[k], word, i)


def _letter_source(per_stage: int = 5):
    alphabet = automata.zero_or_one(len(LETTERS))
    sampler = CurriculumSampler(curriculum("deepltl/letter"), len(LETTERS))
    by_stage = stage_formulas(sampler, LETTERS, per_stage)
    bank = build_bank([f for s in by_stage for f in s], LETTERS, alphabet)
    sizes = [len(s) for s in by_stage]
    return CurriculumProgressionSource(bank, alphabet, sampler, sizes), by_stage


def test_source_draws_the_current_stage_and_the_stage_advances():
    source, by_stage = _letter_source()
    starts = np.cumsum([0] + [len(s) for s in by_stage])
    keys = jax.random.split(jax.random.key(0), 2000)
    reset = jax.jit(jax.vmap(source.reset, in_axes=(0, None)))
    state = source.init_params()
    for stage in range(len(by_stage)):
        tasks = reset(keys, state.replace(stage=jnp.int32(stage)))
        formula, task_id = np.asarray(tasks.formula), np.asarray(tasks.task_id)
        assert ((formula >= starts[stage]) & (formula < starts[stage + 1])).all()
        assert len(np.unique(formula)) == len(by_stage[stage])  # every formula of the stage drawn
        want_id = formula - starts[stage] if stage == 0 else np.full_like(formula, -1)
        np.testing.assert_array_equal(task_id, want_id)
        np.testing.assert_array_equal(np.asarray(source.bank.roots)[formula], tasks.state)
    # stage 0 weighs its tasks by softmax(-success / 0.1): the one unsolved task dominates
    solved = state.replace(task_success=state.task_success.at[:132].set(1.0).at[5].set(0.0))
    formula = np.asarray(reset(keys, solved).formula)
    assert 0.9 < np.mean(formula == 5) < 1.0
    # all of a rollout's episodes succeed: the mean passes 0.95 and the stage advances
    stats = {"_task_id": jnp.arange(64, dtype=jnp.int32).reshape(4, 16) % 132,
             "_finished": jnp.ones((4, 16), bool), "_success": jnp.ones((4, 16), bool)}
    assert int(source.update_params(state, stats).stage) == 1
    assert int(source.update_params(state, {**stats, "_success": stats["_success"].at[0].set(False)}
                                    ).stage) == 0


def test_reach_stay_formulas_are_left_out_of_the_stage_success():
    """ZoneEnv's stage 4 is 60 % reach-stay `!K U G p`, which never progresses to true: its
    episodes carry NEVER_TRUE and the stage passes on the reach-avoid episodes' success."""
    alphabet = automata.zero_or_one(len(COLOURS))
    sampler = CurriculumSampler(curriculum("deepltl/zone"), len(COLOURS))
    by_stage = stage_formulas(sampler, COLOURS, per_stage=20)
    bank = build_bank([f for s in by_stage for f in s], COLOURS, alphabet)
    source = CurriculumProgressionSource(bank, alphabet, sampler, [len(s) for s in by_stage])
    has_g = np.array([" G " in f or f.startswith("F G") for s in by_stage for f in s])
    np.testing.assert_array_equal(np.asarray(source.can_succeed), ~has_g)
    state = source.init_params().replace(stage=jnp.int32(4))
    tasks = jax.vmap(source.reset, in_axes=(0, None))(jax.random.split(jax.random.key(1), 64),
                                                     state)
    stay = has_g[np.asarray(tasks.formula)]
    assert 0 < stay.sum() < 64
    np.testing.assert_array_equal(np.asarray(tasks.task_id), np.where(stay, NEVER_TRUE, -1))
    stats = {"_task_id": tasks.task_id[None], "_finished": jnp.ones((1, 64), bool),
             "_success": jnp.asarray(~stay)[None]}
    assert int(source.update_params(state, stats).stage) == 5
    counted = {**stats, "_task_id": jnp.full((1, 64), -1, jnp.int32)}
    assert int(source.update_params(state, counted).stage) == 4


def test_make_method_samplers_and_errors():
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b", "c"), counts=1))
    method = ltl2action.make_method(world, params, num_formulas=4)
    assert method.follows_curriculum and ltl2action.check_sampler("letter", None) == "curriculum"
    assert int(method.init_task_params().stage) == 0
    by_stage = ltl2action.training_formulas(world.propositions, "letter", 4)
    assert [len(s) for s in by_stage] == [6, 4, 4, 4]  # all 3 x 2 one-step tasks, then draws
    original = ltl2action.make_method(world, params, num_formulas=4, sampler="Eventually_1_2_1_1")
    assert not original.follows_curriculum and original.init_task_params() is None
    assert original.task_metrics(None) == {}
    with pytest.raises(ValueError, match="no curriculum"):
        ltl2action.training_formulas(world.propositions, "arm", 4, sampler="curriculum")
    with pytest.raises(ValueError, match="at least 3 propositions"):
        ltl2action.training_formulas(("a", "b"), "letter", 4)
    with pytest.raises(ValueError, match="unknown LTL2Action sampler"):
        ltl2action.training_formulas(world.propositions, "letter", 4, sampler="Sometimes_1_2")


def test_ltl2action_learns_a_tiny_world_on_the_curriculum():
    """A 5x5 torus with one 'a', 'b' and 'c': the curriculum starts on its six one-step tasks
    (`!b U a`, ...); success rises, and the stage metric is reported."""
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b", "c"), counts=1),
                                      max_steps=6)
    params = world.with_map_bank(jax.random.key(0), params, num_maps=64)
    method = ltl2action.make_method(world, params, num_formulas=8)
    updates = 60  # at 5x the original's learning rate: the tiny world is learnt in 60 updates
    cfg = ltl2action.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * updates,
                                update_epochs=4, num_minibatches=2, lr=1.5e-3)
    _, rows = train_rows(ltl2action, method, cfg, updates)
    first, last = early_late(rows)
    assert first < 0.4 and last > 0.5 and last > first + 0.25, (first, last)
    assert rows[0]["curriculum_stage"] == 0.0
