"""Scoring any policy: `specrl-jax eval --policy RUN_DIR | module:factory`, `specrl-jax bench`,
the suites' versions and the Gymnasium backend (tiny LetterWorld runs)."""

import csv
import json
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax import cli, specs
from specrl_jax.benchmark import agent as agents
from specrl_jax.benchmark import bench, experiment

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
IND = "letter/finite/ind"


def test_a_suite_version_changes_with_its_formulas():
    version = specs.suite_version(IND)
    assert len(version) == 10 and version == specs.suite_info(IND).version
    try:
        first = specs.register_suite("test/bench/v", ["F a", "F b"], tuple("abcdefghijkl")).version
        specs.unregister_suite("test/bench/v")
        same = specs.register_suite("test/bench/v", ["F a", "F b"], tuple("abcdefghijkl")).version
        specs.unregister_suite("test/bench/v")
        changed = specs.register_suite("test/bench/v", ["F a", "F c"], tuple("abcdefghijkl")).version
    finally:
        specs.unregister_suite("test/bench/v")
    assert first == same != changed


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """A module `user_policies` on the path with good and bad factories."""
    (tmp_path / "user_policies.py").write_text(textwrap.dedent("""
        import jax.numpy as jnp
        from specrl_jax.benchmark.agent import Agent

        def right(world):
            return lambda params, obs, task_state, key: jnp.int32(3)

        def not_a_policy(world):
            return 42

        def continuous(world):
            return Agent(lambda p, o, s, k: jnp.zeros(2, jnp.float32), name="continuous")

        def with_epsilon(world):
            return lambda p, o, s, k: (jnp.int32(0), jnp.bool_(False))

        def numpy_policy(world):  # the gymnasium backend's: numpy in, numpy out
            def act(obs, task):
                ap = obs[..., :-1]  # the original's layout: letters, then the agent
                centre = ap.shape[1] // 2
                return ((ap[:, centre - 1].sum(axis=(1, 2)) + 2 * ap[:, :, centre + 1].sum(
                    axis=(1, 2)) + task.q) % 4).astype("int64")
            return act

        NOT_CALLABLE = 3
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "user_policies", raising=False)
    return "user_policies"


@pytest.mark.parametrize("ref, error, message", [
    ("no_such_module_xyz:make", ValueError, "cannot import module 'no_such_module_xyz'"),
    ("user_policies:missing", ValueError, "has no 'missing'"),
    ("user_policies:NOT_CALLABLE", TypeError, "not a factory function"),
    ("user_policies:not_a_policy", TypeError, "is a int, not a policy"),
])
def test_a_bad_factory_is_a_clear_error(user_module, ref, error, message):
    with pytest.raises(error, match=message):
        agents.load(ref, "LetterLTL0-v0")


def test_a_store_cell_without_parameters_says_why_and_what_to_pass_instead():
    with pytest.raises(ValueError, match=r"GCRL-LTL's seed-1 parameters.*are not shipped.*"
                                         r"specrl-jax train --method gcrl --env PointLTL0-v0"):
        agents.load("PointLTL0-v0/gcrl", "PointLTL0-v0")
    with pytest.raises(ValueError, match=r"PointLTL0-v0/gcrl, which PointLTL0MA2-v0/gcrl\+"
                                         r"coordinator runs \(GCRL-LTL's seed-1 parameters"):
        agents.load("PointLTL0MA2-v0/gcrl+coordinator", "PointLTL0MA2-v0")


@pytest.mark.parametrize("factory, message", [
    ("continuous", ("returns actions of shape (2,) and dtype float32; LetterLTL0-v0 takes "
                    "shape () and dtype int32")),
    ("with_epsilon", "does not declare epsilon=True"),
])
def test_a_policy_that_does_not_fit_the_world_is_refused_before_compiling(user_module, factory,
                                                                         message, tmp_path,
                                                                         capsys):
    code = cli.main(["eval", "--env", "LetterLTL0-v0", "--policy", f"user_policies:{factory}",
                     "--suite", IND, "--seeds", "1", "--episodes", "1", "--out", str(tmp_path),
                     "--no-progress"])
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A two-seed GenZ-LTL run directory of a few updates, and its own evaluation."""
    run_dir = tmp_path_factory.mktemp("run")
    overrides = {"total_timesteps": 1024, "num_envs": 8, "num_steps": 64, "num_minibatches": 2,
                 "update_epochs": 1}
    params, _ = experiment.train("genz", "LetterLTL0-v0", run_dir, overrides, num_seeds=2,
                                 map_bank=None, log=lambda line: None)
    own = experiment.evaluate("genz", "LetterLTL0-v0", params, [IND], 2, horizon=8,
                              log=lambda line: None)
    return run_dir, own[0].result.per_seed()


@pytest.mark.slow  # a second training step to compile
def test_a_seed_trained_alone_learns_as_it_does_beside_the_others(tiny_run, tmp_path):
    run_dir, _ = tiny_run
    overrides = {"total_timesteps": 1024, "num_envs": 8, "num_steps": 64, "num_minibatches": 2,
                 "update_epochs": 1}
    second, summary = experiment.train("genz", "LetterLTL0-v0", tmp_path / "run", overrides,
                                       num_seeds=1, first_seed=2, map_bank=None,
                                       log=lambda line: None)
    assert summary["seeds"] == [2]
    both = agents.load(str(run_dir), "LetterLTL0-v0")
    for a, b in zip(jax.tree.leaves(both.params), jax.tree.leaves(second), strict=True):
        np.testing.assert_allclose(a[1:], b, rtol=1e-4, atol=1e-6)


@pytest.mark.slow  # a training step and an evaluator to compile: minutes on a 2-core CPU
def test_a_run_directory_evaluates_as_its_training_run_did(tiny_run, tmp_path):
    run_dir, own = tiny_run
    assert cli.main(["eval", "--env", "LetterLTL0-v0", "--policy", str(run_dir), "--suite", IND,
                     "--episodes", "2", "--horizon", "8", "--no-progress",
                     "--out", str(tmp_path)]) == 0
    (entry,) = json.loads((tmp_path / "eval.json").read_text())["results"]
    assert entry["seeds"] == [1, 2] and entry["method"] == "GenZ-LTL"
    for metric, values in own.items():
        np.testing.assert_array_equal(np.asarray(entry["per_seed"][metric], float), values)
    # --seed 2: the second trained seed alone, under its own evaluation seed
    both = agents.load(str(run_dir), "LetterLTL0-v0")
    second = agents.load(str(run_dir), "LetterLTL0-v0", seed=2)
    assert both.seeds == (1, 2) and second.seeds == (2,)
    for a, b in zip(jax.tree.leaves(both.params), jax.tree.leaves(second.params)):
        np.testing.assert_array_equal(a[1:], b)


def test_a_run_directory_of_another_world_is_refused(tiny_run, tmp_path, capsys):
    run_dir, _ = tiny_run
    code = cli.main(["eval", "--env", "PointLTL0-v0", "--policy", str(run_dir), "--suite",
                     "zone/finite/ind", "--out", str(tmp_path), "--no-progress"])
    assert code == 2
    assert "was trained on LetterLTL0-v0, not PointLTL0-v0" in capsys.readouterr().err
    code = cli.main(["eval", "--env", "LetterLTL0-v0", "--policy", str(run_dir), "--suite", IND,
                     "--seed", "3", "--out", str(tmp_path), "--no-progress"])
    assert code == 2
    assert "holds seeds 1, 2; got --seed 3" in capsys.readouterr().err


def test_bench_writes_a_report_beside_the_baselines(monkeypatch, tmp_path, capsys):
    """The example agent by `module:factory` through `specrl-jax bench` on two LetterWorld
    suites (one finite, one infinite): every report file exists and parses."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    out = tmp_path / "report"
    code = cli.main(["bench", "--policy", "letter_subgoal_agent:make_agent", "--worlds", "letter",
                     "--suite", IND, "--suite", "letter/infinite/rsp", "--seeds", "2",
                     "--episodes", "2", "--horizon", "10", "--out", str(out), "--no-progress"])
    assert code == 0
    assert "letter: eta_s" in capsys.readouterr().out
    document = json.loads((out / "results.json").read_text())
    assert document["backend"] == "jax" and document["name"] == "subgoal-greedy"
    assert document["versions"]["suites"][IND] == specs.suite_version(IND)
    assert set(document["summary"]["letter"]) >= {"eta_s", "eta_v", "mu_acc"}
    (finite,) = [e for e in document["results"] if e["suite"] == IND]
    assert np.asarray(finite["per_seed"]["eta_s"]).shape == (2, len(specs.suite(IND)))
    assert any(b["kind"] == "store" and b["method"] == "GenZ-LTL" for b in finite["baselines"])
    with (out / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    num_specs = len(specs.suite(IND)) + len(specs.suite("letter/infinite/rsp"))
    assert len(rows) == 2 * num_specs and {r["seed"] for r in rows} == {"1", "2"}
    table = (out / "tables.md").read_text()
    assert "| subgoal-greedy |" in table and "GenZ-LTL (reproduction)" in table
    assert "results store LetterLTL0-v0/genz" in table and specs.suite_version(IND) in table
    assert (out / "bench.png").stat().st_size > 5_000
    # with progress lines, the world's summary line is shown once (as it finishes), not again
    assert cli.main(["bench", "--policy", "letter_subgoal_agent:make_agent", "--worlds", "letter",
                     "--suite", IND, "--suite", "letter/infinite/rsp", "--seeds", "2",
                     "--episodes", "2", "--horizon", "10", "--out", str(tmp_path / "again")]) == 0
    shown = capsys.readouterr()
    assert (shown.out + shown.err).count("letter: eta_s") == 1


def _jax_policy(params, obs, task_state, key):
    ap = obs["ap"]
    centre = ap.shape[0] // 2
    return ((ap[centre - 1].sum() + 2 * ap[:, centre + 1].sum() + task_state.q) % 4).astype(jnp.int32)


@pytest.mark.slow  # the evaluator and the vector env's step to compile
def test_the_gymnasium_backend_scores_as_the_jax_backend(user_module, tmp_path):
    """One deterministic policy, written for JAX and for numpy (`user_policies:numpy_policy`
    through `specrl-jax bench --backend gymnasium`): the same episodes on both backends (the
    same layouts, the same automaton steps), so the same metrics per spec and seed."""
    compiled = bench.score(_jax_policy, ["LetterLTL0-v0"], [IND], 2, 3, horizon=12,
                           log=lambda line: None)
    (a,) = compiled.worlds[0].results
    assert a.result.table.success.any() or a.result.table.violation.any()  # not all timeouts
    assert cli.main(["bench", "--backend", "gymnasium", "--policy", "user_policies:numpy_policy",
                     "--worlds", "LetterLTL0-v0", "--suite", IND, "--seeds", "2", "--episodes",
                     "3", "--horizon", "12", "--out", str(tmp_path), "--no-progress"]) == 0
    document = json.loads((tmp_path / "results.json").read_text())
    assert (compiled.backend, document["backend"]) == ("jax", "gymnasium")
    assert "Backend gymnasium" in (tmp_path / "tables.md").read_text()
    (b,) = document["results"]
    for metric, values in a.result.per_seed().items():
        got = np.asarray(b["per_seed"][metric], float)  # JSON null: no episode to average
        np.testing.assert_array_equal(got, values, err_msg=metric)
