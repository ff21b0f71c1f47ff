"""The committed reference parameters still load from the store and act: seed 1 of
LetterLTL0-v0/genz on a handful of IND episodes through `specrl-jax eval --policy CELL` (the
committed result is 1.00 success); clear errors for other worlds and unknown names."""

import json

import jax
import pytest

from specrl_jax import cli
from specrl_jax.benchmark import grid
from specrl_jax.benchmark.agent import load
from specrl_jax.benchmark.store import Store

EVAL = ["eval", "--suite", "letter/finite/ind", "--seeds", "1", "--episodes", "2", "--no-progress"]


@pytest.mark.slow  # compiling the evaluator: about 30 s on a quiet 2-core CPU
def test_committed_parameters_load_and_evaluate(tmp_path):
    store, cell = Store(), grid.cell("LetterLTL0-v0/genz")
    params = store.load_params(cell)
    assert jax.tree.leaves(params)[0].shape[0] == 1  # one seed, given a seed axis
    assert cli.main([*EVAL, "--env", "LetterLTL0-v0", "--policy", cell.name,
                     "--out", str(tmp_path)]) == 0
    (entry,) = json.loads((tmp_path / "eval.json").read_text())["results"]
    assert entry["seeds"] == [1] and entry["method"] == "GenZ-LTL"
    assert entry["summary"]["groups"]["letter/finite/ind"]["eta_s_mean"] >= 0.8
    stored = store.read(cell)["suites"]["letter/finite/ind"]["per_seed"]["eta_s"][0]
    assert min(stored) >= 0.95


def test_a_committed_cell_runs_with_the_options_it_was_trained_with():
    """The grid's image cells now run their convolutions in bfloat16; the PointLTL0Vision
    GenZ-LTL cell was trained in float32 and is loaded so, DeepLTL's as trained."""
    genz, deepltl = grid.cell("PointLTL0Vision-v0/genz"), grid.cell("PointLTL0Vision-v0/deepltl")
    assert genz.options()["image_dtype"] == "bfloat16"
    assert load(genz.name, genz.env_id).method_options == {}
    assert load(deepltl.name, deepltl.env_id).method_options == {"image_dtype": "bfloat16"}


def test_trained_parameters_of_another_world_or_an_unknown_name_are_refused(tmp_path, capsys):
    with pytest.raises(ValueError, match="trained on LetterLTL0-v0, not PointLTL0-v0"):
        load("LetterLTL0-v0/genz", "PointLTL0-v0")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"method": "genz", "env": "PointLTL0-v0"}))
    assert cli.main([*EVAL, "--env", "LetterLTL0-v0", "--policy", str(run)]) == 2
    assert "trained on PointLTL0-v0, not LetterLTL0-v0" in capsys.readouterr().err
    assert cli.main([*EVAL, "--env", "LetterLTL0-v0", "--policy", "nothing/here"]) == 2
    assert "neither a run directory" in capsys.readouterr().err
    with pytest.raises(ValueError, match="no trained parameters"):  # GCRL-LTL's are not kept
        load("PointLTL0-v0/gcrl", "PointLTL0-v0")


def test_suite_versions_mark_entries_scored_before_the_epsilon_fall_back():
    from specrl_jax import specs
    from specrl_jax.benchmark.store import scored_now

    assert specs.suite_info("zone/infinite/per").may_jump
    assert not specs.suite_info("zone/infinite/rsp").may_jump
    assert not specs.suite_info("zone/finite/ind").may_jump
    per = specs.suite_version("zone/infinite/per")
    assert not scored_now("zone/infinite/per", {"is_finite": [False]})  # stored before versions
    assert scored_now("zone/infinite/per", {"suite_version": per})
    assert not scored_now("zone/infinite/per", {"suite_version": "0123456789"})
    assert scored_now("zone/infinite/rsp", {"is_finite": [False]})  # no jumps: scored alike


def test_a_suite_scored_under_an_older_version_is_work_to_redo():
    from specrl_jax import specs
    from specrl_jax.benchmark.store import mark_stale, missing_work

    cell = grid.cell("PointLTL0-v0/genz")
    record = {"training": {"complete": True}, "suites": {
        s: {"seeds": [1, 2, 3, 4, 5], "episodes_per_seed": cell.episodes,
            "suite_version": specs.suite_version(s)} for s in cell.suites}}
    assert missing_work(cell, record) == []
    record["suites"]["zone/infinite/per"]["suite_version"] = "0123456789"
    assert missing_work(cell, record) == ["zone/infinite/per"]
    del record["suites"]["zone/infinite/per"]["suite_version"]  # stored before versions
    assert missing_work(cell, record) == ["zone/infinite/per"]
    record["suites"]["zone/infinite/per"]["suite_version"] = specs.suite_version("zone/infinite/per")
    rsp = record["suites"]["zone/infinite/rsp"]
    record["suites"]["zone/infinite/rsp"] = mark_stale(rsp, "scored by an earlier agent")
    assert missing_work(cell, record) == ["zone/infinite/rsp"]  # the agent changed since
