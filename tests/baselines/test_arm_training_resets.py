"""Arm trainings reset from a bank of exact layouts: every bank layout is the exact sampler's draw
for its own key, so a reset from the bank is distributed as an exact reset (whose distribution
`tests/envs/test_arm_env.py` checks against the original's sampler), and the training env's
resets start each arm at rest in its neutral pose among one of the bank's layouts.

A two-region arm with small sampling rounds keeps the sampler's compile and run to seconds."""

import jax
import numpy as np

from specrl_jax import cli, families
from specrl_jax.baselines import runs
from specrl_jax.benchmark import experiment
from specrl_jax.envs.arm import ArmConfig, ArmEnv
from specrl_jax.envs.arm import layout as layout_lib
from specrl_jax.envs.arm import model as arm_model


def test_the_arm_family_trains_on_a_bank_of_its_own_size(monkeypatch, tmp_path):
    assert families.ARM.map_bank_size("cuda") == 65536 and families.ARM.map_bank_size("cpu") == 512
    assert families.LETTER.map_bank_size("cpu") == 4096
    seen = []

    def stop(method, env_id, out, overrides, seeds, seed=0, **kwargs):
        seen.append(kwargs["map_bank"])
        raise runs.TrainingInterrupted(out, 0)

    monkeypatch.setattr(experiment, "train", stop)
    argv = ["train", "--method", "genz", "--env", "PandaLTLReach0Joints-v0", "--out", str(tmp_path)]
    assert cli.main(argv) == 130 and cli.main([*argv, "--map-bank", "0"]) == 130
    assert seen == [512, None]


def test_training_resets_draw_exact_layouts_from_the_bank(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))  # the bank is sampled, not read
    world = ArmEnv(ArmConfig(colors=("magenta", "blue"), regions_per_color=1, layouts_per_round=8,
                             exact_checks_per_round=2, table_contacts=False))
    key = jax.random.key(3)
    params, method = experiment.with_method("genz", world, world.default_params, 6, key)
    bank = np.asarray(params.map_bank)
    assert bank.shape == (6, 2, 3) and method.env.params is params

    exact = jax.jit(lambda k: layout_lib.sample_centres(k, world.config))
    for row, key_row in list(enumerate(jax.random.split(key, 6)))[::5]:
        centres, ok = exact(key_row)
        assert bool(ok)
        np.testing.assert_array_equal(bank[row], np.asarray(centres))

    task_params = method.init_task_params()
    reset = jax.jit(jax.vmap(method.env.reset, in_axes=(0, None)))
    _, state = reset(jax.random.split(jax.random.key(4), 64), task_params)
    arm = state.env_state
    drawn = np.asarray(arm.region_pos)
    rows = np.argmax(np.all(drawn[:, None] == bank[None], axis=(2, 3)), axis=1)
    np.testing.assert_array_equal(drawn, bank[rows])
    assert set(rows.tolist()) == set(range(6))  # every layout is drawn
    assert np.asarray(arm.layout_ok).all() and not np.asarray(arm.time).any()
    np.testing.assert_allclose(arm.start_qpos, np.broadcast_to(arm_model.NEUTRAL_QPOS, (64, 7)))
    assert not np.asarray(arm.physics.qvel).any()
