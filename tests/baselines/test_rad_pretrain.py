"""RAD-Embeddings' encoder pretraining: the symbol task through the one task loop and the shared
PPO learns (a small encoder, a small bank), and the encoder's parameters round-trip a file."""

import jax
import numpy as np
import pytest

from specrl_jax.automata import zero_or_one
from specrl_jax.baselines.ppo import make_train
from specrl_jax.baselines.rad import pretrain as rad_pretrain


def test_pretraining_on_the_symbol_task_learns_and_saves_the_encoder(tmp_path):
    # 3 letters: a chain state has one token that leads on, one that fails, one that mostly
    # stays, so a random policy succeeds on under half of the conjunctions
    method = rad_pretrain.make_pretrain(zero_or_one(3), ("a", "b", "c"), bank_size=64, seed=0,
                                        hidden=16, num_layers=3)
    updates = 40
    cfg = rad_pretrain.pretrain_config(num_envs=16, num_steps=32, num_minibatches=2,
                                       total_timesteps=16 * 32 * updates)
    runner, metrics = jax.jit(make_train(cfg, method))(jax.random.key(0))
    rate = np.asarray(metrics["successes"]) / np.maximum(np.asarray(metrics["episodes"]), 1)
    assert rate[:5].mean() < 0.55 and rate[-5:].mean() > 0.75, rate
    # the episodes are the task loop's: each ends in success, violation or the horizon
    ended = metrics["successes"] + metrics["violations"] + metrics["timeouts"]
    np.testing.assert_allclose(ended, metrics["episodes"])
    params = rad_pretrain.encoder_params(runner.params)
    path = tmp_path / "enc.msgpack"
    rad_pretrain.save_encoder(path, params, {"note": "test"})
    with pytest.raises(ValueError, match="reads 4 symbols"):
        rad_pretrain.load_encoder(path, 13)
