"""The `specrl-jax` command line end to end on a tiny configuration, and its errors."""

import json

import pytest

from specrl_jax import cli


def test_eval_end_to_end(tmp_path, capsys):
    code = cli.main(["eval", "--env", "LetterLTL0-v0", "--policy", "oracle",
                     "--suite", "letter/complexity_paper/reach_avoid/seq2_disj0",
                     "--seeds", "2", "--episodes", "3", "--horizon", "30", "--trajectories", "2",
                     "--out", str(tmp_path), "--no-progress"])
    assert code == 0
    data = json.loads((tmp_path / "eval.json").read_text())
    (entry,) = data["results"]
    assert entry["seeds"] == [1, 2] and entry["horizon"] == 30 and len(entry["specs"]) == 3
    suite = entry["summary"]["groups"]["letter/complexity_paper/reach_avoid/seq2_disj0"]
    assert suite["eta_s_mean"] == 1.0 and suite["eta_v_mean"] == 0.0  # the planner is optimal
    assert 2 <= suite["mu_mean"] <= 30
    table = (tmp_path / "eval.md").read_text()
    assert "| LetterLTL0-v0 | letter/complexity_paper/reach_avoid/seq2_disj0 | 1.00±0.00 |" in table
    assert table in capsys.readouterr().out
    for plot in ("complexity.png", "trajectories.png"):
        assert (tmp_path / plot).stat().st_size > 5_000


def test_train_gcrl_end_to_end(tmp_path, monkeypatch, capsys):
    """`specrl-jax train` on a method with a phase after PPO (GCRL-LTL's value function from the
    policy's trajectories) writes both networks and evaluates every Letter suite with them, at the
    network widths given as method options. An identical second run reads its three traced
    programs from the disk cache and trains the same parameters."""
    from flax import serialization

    from specrl_jax import cache

    programs = tmp_path / "programs"  # the first run traces its programs
    monkeypatch.setattr(cache, "programs_dir", lambda: str(programs))
    argv = ["train", "--method", "gcrl", "--env", "LetterLTL0-v0", "--total-steps", "512",
            "--num-envs", "8", "--num-steps", "16", "--map-bank", "64",
            "--method-option", "trunk=(32,)", "--method-option", "value_features=(16, 16)"]
    code = cli.main([*argv, "--eval-episodes", "1", "--out", str(tmp_path)])
    assert code == 0 and "program cache" not in capsys.readouterr().out
    assert cli.main([*argv, "--out", str(tmp_path / "again")]) == 0
    assert capsys.readouterr().out.count("traced program read from the program cache") == 3
    params = (tmp_path / "params.msgpack").read_bytes()
    assert (tmp_path / "again" / "params.msgpack").read_bytes() == params
    stored = serialization.msgpack_restore(params)
    assert set(stored) == {"policy", "gcvf"}
    assert stored["gcvf"]["params"]["Dense_1"]["kernel"].shape[-2:] == (16, 16)
    results = json.loads((tmp_path / "eval.json").read_text())["results"]
    assert [r["suite"] for r in results] == ["letter/finite/ind", "letter/finite/ood",
                                             "letter/infinite/rsp", "letter/infinite/rec"]
    assert all(r["method"] == "GCRL-LTL" and r["seeds"] == [1] for r in results)
    summary = json.loads((tmp_path / "train_summary.json").read_text())
    assert summary["env_steps_per_seed"] == 512


def test_listings(capsys):
    assert cli.main(["envs"]) == 0
    assert "LetterLTL0-v0" in capsys.readouterr().out
    assert cli.main(["specs", "--prefix", "letter/finite", "--formulas"]) == 0
    out = capsys.readouterr().out
    assert "letter/finite/ind" in out and "!(a | b) U (c & (!(d | e) U f))" in out
    assert "zone/" not in out


@pytest.mark.parametrize("change, message", [
    ({"--policy": "greedy"}, "unknown policy 'greedy'; known policies: random, oracle"),
    ({"--suite": "letter/finite/nope"}, "unknown suite 'letter/finite/nope'"),
    ({"--suite": "zone/finite/ind"}, "over propositions"),
    ({"--env": "LetterLTL9-v0"}, "unknown env ID 'LetterLTL9-v0'"),
])
def test_clear_errors(change, message, tmp_path, capsys):
    options = {"--env": "LetterLTL0-v0", "--policy": "random", "--suite": "letter/finite/ind",
               "--seeds": "1", "--out": str(tmp_path)}
    options.update(change)
    argv = ["eval", "--no-progress"] + [x for pair in options.items() for x in pair]
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err


def test_oracle_needs_letter_world():
    class Arena:
        action_space = None

    with pytest.raises(ValueError, match="needs LetterWorld"):
        cli.make_policy("oracle", Arena())


def test_env_options_parse_as_literals_and_reach_the_world():
    import argparse

    from specrl_jax.benchmark import experiment

    assert cli.env_option("image_size=64") == ("image_size", 64)
    assert cli.env_option("partial=True") == ("partial", True)
    assert cli.env_option("twins_apart=true") == ("twins_apart", True)
    assert cli.env_option("partial=FALSE") == ("partial", False)
    assert cli.env_option("physics=warp") == ("physics", "warp")
    with pytest.raises(argparse.ArgumentTypeError, match="KEY=VALUE"):
        cli.env_option("image_size")
    _, params, method, _ = experiment.build("genz", "LetterLTL0-v0", {}, None, None, {"max_steps": 40})
    assert int(params.max_steps) == 40 and int(method.env.params.max_steps) == 40


