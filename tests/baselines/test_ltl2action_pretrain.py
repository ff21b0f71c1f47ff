"""LTL2Action's optional encoder pretraining (LTLBootcamp): the symbol task learns through the one
task loop, its R-GCN starts (and, frozen, stays) the downstream network's encoder, the file
round-trips, and `prepare_training` pretrains on the method's own formulas when asked."""

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny_learning import early_late, train_rows

import specrl_jax
from specrl_jax.automata import zero_or_one
from specrl_jax.baselines import ltl2action
from specrl_jax.baselines.ltl2action import pretrain as ltl2action_pretrain
from specrl_jax.baselines.ppo import make_train
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.tasks.progression import num_features

PROPS = ("a", "b", "c")
# a random letter keeps an until's left side with probability 1/2: random success about 0.375
FORMULAS = ["!a U b", "!b U c", "!c U a",
            "!a U (b & (!a U c))", "!b U (c & (!b U a))", "!c U (a & (!c U b))"]


def _same(x, y) -> bool:
    return all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(x), jax.tree.leaves(y)))


def test_bootcamp_learns_and_its_encoder_starts_the_downstream_network(tmp_path):
    bootcamp = ltl2action.make_bootcamp(zero_or_one(3), PROPS, FORMULAS)
    assert bootcamp.network.num_actions == 3  # the letters, never the empty assignment
    updates = 40
    cfg = ltl2action_pretrain.bootcamp_config(num_envs=16, num_steps=32, num_minibatches=2,
                                              total_timesteps=16 * 32 * updates)
    runner, rows = train_rows(ltl2action, bootcamp, cfg, updates)
    first, last = early_late(rows)
    assert first < 0.55 and last > 0.85, (first, last)
    encoder = ltl2action_pretrain.encoder_params(runner.params)

    path = tmp_path / "l2a_encoder.msgpack"
    ltl2action_pretrain.save_encoder(path, encoder, {"note": "test"})
    assert _same(ltl2action_pretrain.load_encoder(path, 3), encoder)
    # the original's token vocabulary is 22 wide up to 13 propositions, wider beyond
    with pytest.raises(ValueError, match="30 propositions need 39"):
        ltl2action_pretrain.load_encoder(path, 30)
    with pytest.raises(ValueError, match="no pretrained LTL2Action encoder"):
        ltl2action_pretrain.load_encoder(tmp_path / "missing.msgpack", 3)

    # downstream: a 5x5 letter world; the network starts from the file's encoder, and a frozen
    # encoder stays as it was through an update while the rest of the network moves
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=PROPS, counts=1),
                                      max_steps=6)
    params = world.with_map_bank(jax.random.key(0), params, num_maps=16)
    method = ltl2action.make_method(world, params, formulas=FORMULAS, encoder=str(path),
                                    freeze_encoder=True)
    down_cfg = ltl2action.ppo_config(num_envs=8, num_steps=8, num_minibatches=2,
                                     total_timesteps=64)
    trainer = make_train(down_cfg, method)
    start = jax.jit(trainer.init)(jax.random.key(2))
    assert _same(ltl2action_pretrain.encoder_params(start.params), encoder)
    after, _ = jax.jit(trainer.updates, static_argnums=1)(start, 1)
    assert _same(ltl2action_pretrain.encoder_params(after.params), encoder)
    assert not _same(after.params["params"]["Dense_0"], start.params["params"]["Dense_0"])

    wider = {"params": {**encoder["params"], "Dense_0": {"kernel": np.zeros((41, 32)),
                                                          "bias": np.zeros(32)}}}
    with pytest.raises(ValueError, match="do not match"):
        ltl2action.with_encoder(start.params, wider)


def test_prepare_training_pretrains_on_the_methods_own_formulas_when_asked(monkeypatch, tmp_path):
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=PROPS, counts=1),
                                      max_steps=6)
    calls = []

    def fake_pretrain(alphabet, propositions, formulas, stages, family, key, steps, log):
        calls.append((alphabet.shape, propositions, formulas, stages, family, steps))
        return {"params": {"marker": np.ones(2)}}

    monkeypatch.setattr(ltl2action, "pretrain_encoder", fake_pretrain)
    cfg = ltl2action.ppo_config(total_timesteps=1024)
    plain = ltl2action.make_method(world, params, formulas=FORMULAS)
    assert ltl2action.prepare_training(plain, jax.random.key(0), cfg) is plain
    # the default training formulas: the curriculum's stages, which the bootcamp follows too
    asked = ltl2action.make_method(world, params, num_formulas=8, pretrain_steps=5000)
    assert asked.stages is not None and len(asked.stages) == 4
    assert sum(asked.stages) == len(asked.formulas)
    ready = ltl2action.prepare_training(asked, jax.random.key(0), cfg)
    assert calls == [((4, 3), PROPS, asked.formulas, asked.stages, "letter", 5000)]
    assert ready.encoder["params"]["marker"].shape == (2,)
    # a method that already has its encoder is not pretrained again
    assert ltl2action.prepare_training(ready, jax.random.key(0), cfg) is ready
    # a run directory keeps the encoder: a resumed run reads it instead of pretraining again
    saved = tmp_path / "prepared.msgpack"
    ltl2action.prepare_training(asked, jax.random.key(0), cfg, saved=saved)
    resumed = ltl2action.prepare_training(asked, jax.random.key(0), cfg, saved=saved)
    assert len(calls) == 2
    np.testing.assert_array_equal(resumed.encoder["params"]["marker"], np.ones(2))
    with pytest.raises(ValueError, match="pretrain_steps must be >= 0"):
        ltl2action.make_method(world, params, formulas=FORMULAS, pretrain_steps=-1)


@pytest.mark.parametrize("env_id", ["LetterLTL0-v0", "PointLTL0-v0"])
def test_committed_encoders_fit_the_networks_of_their_worlds(env_id):
    """The shipped encoders (baselines/data, README) load for their world's propositions,
    have the shapes of that world's R-GCN, and say which world they were pretrained on."""
    data = Path(specrl_jax.__file__).resolve().parent / "baselines" / "data"
    stem = data / f"ltl2action_encoder_{'letter' if env_id.startswith('Letter') else 'zone'}"
    assert json.loads(stem.with_suffix(".json").read_text())["env"] == env_id
    world, _ = specrl_jax.make(env_id)
    num_props = len(world.propositions)
    encoder = ltl2action_pretrain.load_encoder(stem.with_suffix(".msgpack"), num_props)
    graph = jnp.zeros((1, 4), jnp.int32)
    fresh = jax.eval_shape(ltl2action.networks.RGCNEncoder(num_features(num_props)).init,
                           jax.random.key(0), graph, graph - 1, graph)
    assert jax.tree.map(np.shape, fresh) == jax.tree.map(np.shape, encoder)
    assert all(np.isfinite(leaf).all() for leaf in jax.tree.leaves(encoder))
