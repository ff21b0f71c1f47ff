"""First use and bad input at the command line and the evaluator: numeric arguments, seeds,
resuming a run directory only with its own settings, damaged checkpoints, unwritable outputs."""

import json

import jax
import pytest

import specrl_jax
from specrl_jax import cli
from specrl_jax.baselines import runs
from specrl_jax.baselines.ppo import PPOConfig, make_train
from specrl_jax.eval import evaluate, random_policy
from chain import ChainMethod


@pytest.mark.parametrize("argv, message", [
    (["train", "--method", "genz", "--total-steps", "0"], "expected an integer >= 1, got 0"),
    (["train", "--method", "genz", "--num-envs", "0"], "expected an integer >= 1, got 0"),
    (["train", "--method", "genz", "--seeds", "0"], "expected an integer >= 1, got 0"),
    (["train", "--method", "genz", "--seeds", "-1"], "expected an integer >= 1, got -1"),
    (["run", "--episodes", "x"], "expected an integer >= 1, got 'x'"),
    (["eval", "--env", "LetterLTL0-v0", "--policy", "random", "--suite", "s", "--seeds", "0"],
     "expected an integer >= 1"),
])
def test_numeric_arguments_are_checked_at_the_boundary(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    for name in ("envs", "specs", "eval", "train", "run"):
        assert name in out


def test_evaluate_rejects_bad_and_duplicate_seeds():
    env, params = specrl_jax.make("LetterLTL0-v0")
    for seeds, message in (([-1], "0 .. 2\\*\\*32 - 1, got -1"), ([1, 2, 1], "distinct"),
                           ([], "seeds is empty")):
        with pytest.raises(ValueError, match=message):
            evaluate(random_policy(env), (env, params), ["F a"], seeds=seeds, episodes_per_seed=1)


def _trainer(**overrides):
    config = PPOConfig(**{"num_envs": 4, "num_steps": 8, "num_minibatches": 2, "update_epochs": 1,
                          "total_timesteps": 4 * 8 * 3, **overrides})
    return make_train(config, ChainMethod())


def test_a_run_directory_resumes_only_with_its_own_settings(tmp_path):
    quiet = {"log": lambda s: None, "chunk_updates": 2}
    runs.train_in_run_dir(_trainer(), jax.random.key(0), tmp_path, **quiet)
    config_before = (tmp_path / "config.json").read_text()
    with pytest.raises(ValueError, match=r"other settings \(ppo.total_timesteps: 96 -> 48\).*"
                                         r"new --out, or pass --restart"):
        runs.train_in_run_dir(_trainer(total_timesteps=48), jax.random.key(0), tmp_path, **quiet)
    with pytest.raises(ValueError, match="num_seeds: 1 -> 2"):
        runs.train_in_run_dir(_trainer(), jax.random.key(0), tmp_path, num_seeds=2, **quiet)
    assert (tmp_path / "config.json").read_text() == config_before  # metadata not rewritten
    runner = runs.train_in_run_dir(_trainer(total_timesteps=48), jax.random.key(0), tmp_path,
                                   restart=True, **quiet)
    assert int(runner.update[0]) == 1
    assert json.loads((tmp_path / "config.json").read_text())["ppo"]["total_timesteps"] == 48
    assert len(runs.read_metrics(tmp_path)) == 1


def test_a_damaged_checkpoint_is_named(tmp_path):
    quiet = {"log": lambda s: None, "chunk_updates": 2, "max_updates": 2}
    runs.train_in_run_dir(_trainer(), jax.random.key(0), tmp_path, **quiet)
    (tmp_path / runs.CHECKPOINT).write_bytes(b"\x93\x01")
    with pytest.raises(ValueError, match=f"checkpoint {tmp_path / runs.CHECKPOINT} cannot be read"):
        runs.train_in_run_dir(_trainer(), jax.random.key(0), tmp_path, **quiet)


def test_an_unwritable_output_directory_is_a_clear_error(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    code = cli.main(["eval", "--env", "LetterLTL0-v0", "--policy", "random", "--suite",
                     "letter/finite/ind", "--out", str(blocker / "out"), "--seeds", "1",
                     "--episodes", "1", "--no-progress"])
    assert code == 2
    assert "error: Not a directory" in capsys.readouterr().err


def test_an_unknown_method_option_lists_the_accepted_ones(capsys):
    code = cli.main(["train", "--method", "ltl2action", "--method-option", "encoder_path=x",
                     "--total-steps", "8", "--out", "/nonexistent/never-written"])
    assert code == 2
    err = capsys.readouterr().err
    assert "LTL2Action has no option 'encoder_path'; accepted:" in err
    for name in ("sampler", "encoder", "freeze_encoder", "pretrain_steps"):
        assert name in err.split("accepted:")[1]


def test_method_options_reach_training_and_evaluation(monkeypatch, tmp_path):
    from specrl_jax.baselines import experiment

    seen = {}

    def fake_train(method, env_id, out, overrides, seeds, seed, **kwargs):
        seen["train"] = kwargs["method_options"]
        return {"w": jax.numpy.zeros((1, 2))}, {"env_steps_per_seed": 8, "env_steps_per_s": 1.0}

    def fake_evaluate(method, env_id, params, suites, episodes, **kwargs):
        seen["evaluate"] = kwargs["method_options"]
        return []

    monkeypatch.setattr(experiment, "train", fake_train)
    monkeypatch.setattr(experiment, "evaluate", fake_evaluate)
    assert cli.main(["train", "--method", "ltl2action", "--out", str(tmp_path), "--eval-episodes", "1",
                     "--method-option", "encoder=runs/enc.msgpack", "--method-option",
                     "freeze_encoder=True", "--method-option", "pretrain_steps=1000"]) == 0
    expected = {"encoder": "runs/enc.msgpack", "freeze_encoder": True, "pretrain_steps": 1000}
    assert seen == {"train": expected, "evaluate": expected}
