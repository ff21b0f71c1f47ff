"""RAD-Embeddings downstream: policies conditioned on a frozen DFA embedding learn a tiny world
through the task loop and the shared PPO, and the test-time agent, tracking the evaluated specs'
DFAs through the automaton states, solves them under `eval.evaluate`."""

import jax
import numpy as np
import pytest
from tiny_learning import early_late, train_rows

from specrl_jax import automata
from specrl_jax.automata import rad_sampler
from specrl_jax.baselines import rad
from specrl_jax.baselines.rad.encoder import RADEncoder, build_graphs, graph_of
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.eval import evaluate

TINY_FORMULAS = ["F a", "F b", "!a U b", "!b U a"]


def test_rad_learns_a_tiny_letter_world_and_its_policy_solves_the_compiled_specs():
    # 5x5 torus, one 'a' and one 'b': the DFA says which letter to reach (and which to avoid)
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=1),
                                      max_steps=6)
    params = world.with_map_bank(jax.random.key(0), params, num_maps=64)
    compiled = automata.compile_suite(TINY_FORMULAS, world.propositions, world.alphabet)
    bank, _ = rad_sampler.bank_of_specs(compiled)
    # a frozen, randomly initialised encoder (small, to compile fast): its embeddings already
    # tell the four tasks apart
    graph = graph_of(build_graphs(bank), bank, 0, np.zeros(1, np.int32))
    encoder_params = RADEncoder(hidden=16, num_layers=2).init(jax.random.key(2), graph)
    method = rad.make_method(world, params, bank=bank, encoder_params=encoder_params,
                             encoder_layers=2)
    updates = 50
    cfg = rad.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * updates,
                         update_epochs=4, num_minibatches=2, lr=1e-3)
    runner, rows = train_rows(rad, method, cfg, updates, optimised=False)  # level 0: 32 -> 23 s
    first, last = early_late(rows)
    assert first < 0.35 and last > 0.5, (first, last)

    policy = rad.make_policy(method.network, world.alphabet, world.obs_kinds,
                             encoder_params=encoder_params, encoder_layers=2)
    result = evaluate(policy, (world, params), compiled, seeds=[1], episodes_per_seed=32,
                      policy_params=runner.params)
    success = np.asarray(result.table.success).mean()
    assert success > 0.5, success
    with pytest.raises(ValueError, match="not co-safe"):
        evaluate(policy, (world, params), ["G F a"], seeds=[1], episodes_per_seed=1,
                 policy_params=runner.params)
    assert rad.usable_suites(["letter/finite/ind", "letter/infinite/rec"],
                             log=lambda _: None) == ["letter/finite/ind"]
