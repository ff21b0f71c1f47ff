"""RAD-Embeddings on the DeepLTL curriculum (tasks/dfa_source.py `CurriculumDFASource`): the
bank's DFAs decide the stage formulas as their automata do, reach-stay tasks are left out, the
source draws from the current stage and advances it, and the method trains through the task
loop with the stage reported."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny_learning import early_late, train_rows

from specrl_jax import automata
from specrl_jax.automata import translate
from specrl_jax.baselines import rad
from specrl_jax.baselines.rad.encoder import RADEncoder, graph_of
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.specs import CurriculumSampler, curriculum
from specrl_jax.tasks.curriculum_progression import stage_formulas
from specrl_jax.tasks.dfa_source import CurriculumDFASource, curriculum_dfas

LETTERS = tuple("abcdefghijkl")
COLOURS = ("blue", "green", "magenta", "yellow")


def _tasks(name: str, props: tuple[str, ...], per_stage: int, seed: int = 0):
    sampler = CurriculumSampler(curriculum(name), len(props))
    alphabet = automata.zero_or_one(len(props))
    return sampler, alphabet, curriculum_dfas(sampler, props, alphabet, per_stage, seed)


@pytest.mark.parametrize("name,props", [("deepltl/letter", LETTERS), ("deepltl/zone", COLOURS)])
def test_bank_dfas_decide_the_stage_formulas_as_their_automata(name, props):
    """On random words, DFA row k accepts exactly where formula k's automaton reaches a success
    state, and is dead exactly where the automaton is violated; the rows are the stages'
    co-safe formulas in order, the reach-stay ones (not co-safe) left out."""
    sampler, alphabet, tasks = _tasks(name, props, per_stage=16, seed=2)
    drawn = stage_formulas(sampler, props, 16, seed=2)
    for stage, kept in zip(drawn, tasks.formulas):
        finite = [f for f in stage if translate.translate(f, props, alphabet).is_finite]
        assert kept == finite and all(" G " not in f for f in kept)
    left_out = sum(map(len, drawn)) - sum(map(len, tasks.formulas))
    assert (left_out > 0) == (name == "deepltl/zone"), left_out  # Letter has no reach-stay task
    formulas = [f for stage in tasks.formulas for f in stage]
    delta, accepting, live = (np.asarray(x)[:, 0] for x in (tasks.bank.delta,
                                                             tasks.bank.accepting,
                                                             tasks.bank.live))
    rng = np.random.default_rng(0)
    outcomes = {"accept": 0, "dead": 0, "open": 0}
    for k in range(0, len(formulas), 3):
        aut = translate.translate(formulas[k], props, alphabet)
        for _ in range(16):
            q, state = 0, aut.init
            for symbol in rng.integers(0, len(alphabet), rng.integers(1, 25)):
                q, state = delta[k, q, symbol], aut.delta[state, symbol]
                assert accepting[k, q] == aut.success[state], (formulas[k], k)
                assert (not live[k, q]) == aut.violation[state], (formulas[k], k)
            outcomes["accept" if accepting[k, q] else "dead" if not live[k, q] else "open"] += 1
    assert min(outcomes.values()) > 10, outcomes  # each verdict was seen


def test_zone_mixed_stages_keep_their_reach_avoid_draws():
    """ZoneEnv's stages 4-6 mix reach-stay (60 / 20 / 20 %) into reach-avoid draws: only the
    reach-avoid ones stay, the enumerated stages 0-3 whole."""
    sampler, _, tasks = _tasks("deepltl/zone", COLOURS, per_stage=200)
    sizes = tasks.stage_sizes
    assert sizes[:4] == [4, 12, 12, 72]
    assert 50 < sizes[4] < 110 and 140 < sizes[5] < 190 and 140 < sizes[6] < 190, sizes
    assert tasks.bank.size == sum(sizes) and tasks.bank.max_conjuncts == 1


def test_source_draws_the_current_stage_and_the_stage_advances():
    sampler, alphabet, tasks = _tasks("deepltl/letter", LETTERS, per_stage=5)
    source = CurriculumDFASource(tasks.bank, alphabet, sampler, tasks.stage_sizes)
    starts = np.cumsum([0, *tasks.stage_sizes])
    keys = jax.random.split(jax.random.key(0), 2000)
    reset = jax.jit(jax.vmap(source.reset, in_axes=(0, None)))
    state = source.init_params()
    for stage in range(len(tasks.stage_sizes)):
        drawn = reset(keys, state.replace(stage=jnp.int32(stage)))
        index, task_id = np.asarray(drawn.index), np.asarray(drawn.task_id)
        assert ((index >= starts[stage]) & (index < starts[stage + 1])).all()
        assert len(np.unique(index)) == tasks.stage_sizes[stage]  # every task of the stage
        want_id = index - starts[stage] if stage == 0 else np.full_like(index, -1)
        np.testing.assert_array_equal(task_id, want_id)
        assert (np.asarray(drawn.q) == 0).all()
    assert source.next_index(drawn) is None
    # stage 0 weighs its tasks by softmax(-success / 0.1): the one unsolved task dominates
    solved = state.replace(task_success=state.task_success.at[:132].set(1.0).at[7].set(0.0))
    assert 0.9 < np.mean(np.asarray(reset(keys, solved).index) == 7) < 1.0
    stats = {"_task_id": jnp.arange(64, dtype=jnp.int32).reshape(4, 16) % 132,
             "_finished": jnp.ones((4, 16), bool), "_success": jnp.ones((4, 16), bool)}
    assert int(source.update_params(state, stats).stage) == 1
    failed = {**stats, "_success": stats["_success"].at[0].set(False)}
    assert int(source.update_params(state, failed).stage) == 0
    # a fixed index (evaluation) is that row, outside the curriculum
    fixed = source.reset(keys[0], state, jnp.int32(starts[3] + 1))
    assert int(fixed.index) == starts[3] + 1 and int(fixed.task_id) == -1


def test_make_method_samplers_and_errors():
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b", "c"), counts=1))
    assert rad.check_sampler("letter", None) == rad.check_sampler("zone", None) == "curriculum"
    assert rad.check_sampler("arm", None) == rad.check_sampler("letter", "rad") == "rad"
    with pytest.raises(ValueError, match="no curriculum"):
        rad.check_sampler("arm", "curriculum")
    with pytest.raises(ValueError, match="unknown RAD sampler"):
        rad.check_sampler("letter", "Until_1_2_1_1")
    with pytest.raises(ValueError, match="no sampler for world family"):
        rad.make_method(world, params, "planet", sampler="curriculum")
    _, sizes, bank, _ = rad.curriculum_bank(world.propositions, world.alphabet, "letter", 4)
    assert sizes == [6, 4, 4, 4] and bank.size == 18  # all 3 x 2 one-step tasks, then draws


def test_rad_trains_a_tiny_world_on_the_curriculum():
    """A 5x5 torus with one 'a', 'b' and 'c': the curriculum starts on its six one-step tasks
    (`!b U a`, ...) as DFAs under a frozen random encoder (small, but of the original's 8
    rounds: with 2 the start state never hears which letter is to be avoided); success rises,
    violations fall, the stage is reported."""
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b", "c"), counts=1),
                                      max_steps=6)
    params = world.with_map_bank(jax.random.key(0), params, num_maps=64)
    _, _, bank, graphs = rad.curriculum_bank(world.propositions, world.alphabet, "letter", 4)
    graph = graph_of(graphs, bank, 0, np.zeros(1, np.int32))
    encoder_params = RADEncoder(hidden=16, num_layers=8).init(jax.random.key(2), graph)
    method = rad.make_method(world, params, sampler="curriculum", per_stage=4,
                             encoder_params=encoder_params)
    assert isinstance(method.env.task.source, CurriculumDFASource)
    assert method.env.task.source.bank is bank
    updates = 180  # success passes 0.4 after 110-150 updates, depending on XLA:CPU's numerics
    cfg = rad.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * updates,
                         update_epochs=4, num_minibatches=2, lr=1e-3)
    _, rows = train_rows(rad, method, cfg, updates)
    success = early_late(rows, "success_rate", window=10)
    violation = early_late(rows, "violation_rate", window=10)
    assert success[0] < 0.3 and success[1] > 0.4, success
    assert violation[1] < violation[0], violation
    assert {r["curriculum_stage"] for r in rows} == {0.0}  # stage 0 passes at 0.95 only
