"""First use and bad input at the command line and the evaluator: numeric arguments, seeds,
resuming a run directory only with its own settings, damaged checkpoints, unwritable outputs."""

import json
import warnings

import jax
import pytest
from chain import ChainMethod

import specrl_jax
from specrl_jax import cli
from specrl_jax.baselines import runs
from specrl_jax.baselines.ppo import PPOConfig, make_train
from specrl_jax.eval import evaluate, random_policy


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
    from specrl_jax.benchmark import experiment

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


@pytest.fixture
def no_map_bank(monkeypatch):
    """LetterWorld's map bank (the expensive set-up) fails the test if it is built."""
    from specrl_jax.envs.letter import LetterWorld

    def built(*args, **kwargs):
        raise AssertionError("the map bank was built before the bad argument was reported")

    monkeypatch.setattr(LetterWorld, "with_map_bank", built)


@pytest.mark.parametrize("argv, message", [
    (["--num-envs", "7", "--num-steps", "3"], "num_envs * num_steps = 21 is not divisible by"),
    (["--out", "FILE"], "cannot create the run directory"),
    (["--method", "ltl2action", "--method-option", "encoder=/nonexistent/enc.msgpack"],
     "method option encoder='/nonexistent/enc.msgpack': no such file"),
    (["--out", "DAMAGED"], "config.json cannot be read (Expecting value"),
])
def test_bad_training_arguments_fail_before_the_map_bank(argv, message, tmp_path, capsys,
                                                         no_map_bank):
    (tmp_path / "file").write_text("")
    damaged = tmp_path / "damaged"  # a run directory whose config.json was cut short
    damaged.mkdir()
    (damaged / "metrics.jsonl").write_text("")
    (damaged / "config.json").write_text('{"ppo": ')
    paths = {"FILE": str(tmp_path / "file"), "DAMAGED": str(damaged)}
    base = ["train", "--method", "genz", "--total-steps", "64", "--out", str(tmp_path / "run")]
    assert cli.main(base + [paths.get(a, a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert message in err
    if "DAMAGED" in argv:
        assert f"{damaged / 'config.json'} cannot be read" in err and "--restart" in err


def test_ctrl_c_names_the_checkpointed_update_and_the_same_call_resumes(tmp_path, monkeypatch):
    # Ctrl-C after the second chunk's rows are written, before its checkpoint
    real, saves = runs.save_checkpoint, []

    def interrupted_on_the_second(path, runner):
        saves.append(path)
        if len(saves) == 2:
            raise KeyboardInterrupt
        real(path, runner)

    lines = []
    options = {"log": lines.append, "chunk_updates": 2, "first_chunk": 1}
    monkeypatch.setattr(runs, "save_checkpoint", interrupted_on_the_second)
    with pytest.raises(runs.TrainingInterrupted,
                       match="interrupted at update 1; run the same command to resume"):
        runs.train_in_run_dir(_trainer(), jax.random.key(0), tmp_path, **options)
    compiled = [line for line in lines if line.startswith("compil")]
    assert sorted(line.split(" in ")[0] for line in compiled) == sorted([  # the two overlap
        "compiling the initial state (env reset, network init) ...",
        "compiled the initial state (env reset, network init)",
        "compiling the training step ...", "compiled the training step"])
    progress = [line for line in lines if not line.startswith("compil")]
    assert progress[0].startswith("update 1/3 ") and "compilation included" in progress[0]
    assert progress[1].startswith("update 3/3 ") and "compilation" not in progress[1]
    monkeypatch.setattr(runs, "save_checkpoint", real)
    runner = runs.train_in_run_dir(_trainer(), jax.random.key(0), tmp_path, **options)
    progress = [line for line in lines if not line.startswith("compil")]
    assert "resumed at update 1" in progress[2] and int(runner.update[0]) == 3
    assert [r["update"] for r in runs.read_metrics(tmp_path)] == [1, 2, 3]


def test_ctrl_c_at_the_command_line_is_one_line(monkeypatch, tmp_path, capsys):
    from specrl_jax.benchmark import experiment

    def interrupted(*args, **kwargs):
        raise runs.TrainingInterrupted(tmp_path, 7)

    monkeypatch.setattr(experiment, "train", interrupted)
    assert cli.main(["train", "--method", "genz", "--out", str(tmp_path)]) == 130
    assert capsys.readouterr().err.splitlines()[-1] == (
        "specrl-jax train: interrupted at update 7; run the same command to resume")


def test_the_cpu_announces_the_steps_it_trains_and_a_small_map_bank(monkeypatch, tmp_path, capsys):
    from specrl_jax.benchmark import experiment

    seen = []

    def stop(method, env_id, out, overrides, seeds, seed=0, **kwargs):
        seen.append(kwargs["map_bank"])
        raise runs.TrainingInterrupted(out, 0)

    monkeypatch.setattr(experiment, "train", stop)
    assert cli.main(["run", "--out", str(tmp_path)]) == 130
    assert ("training GenZ-LTL on LetterLTL0-v0: 1 x 198,656 steps (200,000 rounded down to whole "
            "updates of 2,048)") in capsys.readouterr().out
    assert cli.main(["train", "--method", "genz", "--out", str(tmp_path / "t")]) == 130
    assert seen == [4096, 4096]


def test_a_camera_world_at_256_pixels_on_a_cpu_is_warned_about():
    from types import SimpleNamespace

    from specrl_jax.benchmark import experiment
    from specrl_jax.envs.zone.config import level_config

    with pytest.warns(UserWarning, match="256 x 256 pixels on a CPU.*--env-option image_size=64"):
        experiment.warn_slow_camera(SimpleNamespace(config=level_config("Point", 0, False, False,
                                                                        vision=True)), "cpu")
    small = level_config("Point", 0, False, False, vision=True, image_size=64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        experiment.warn_slow_camera(SimpleNamespace(config=small), "cpu")
        experiment.warn_slow_camera(SimpleNamespace(config=level_config("Point", 0, False, False,
                                                                        vision=True)), "gpu")
