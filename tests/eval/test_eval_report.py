"""Reports: the Markdown layout, JSON contents and plots from hand-made results."""

import json

import numpy as np

from specrl_jax.eval.evaluate import EvalResult
from specrl_jax.eval.metrics import EpisodeTable
from specrl_jax.eval.report import (
    SuiteResult,
    markdown_tables,
    plot_complexity,
    plot_trajectories,
    write_json,
)


def result(success, violation, steps, accepting, finite=True, aborted=None) -> EvalResult:
    """Fields [seeds=2, specs=1, episodes=2] from [seed][episode] lists."""
    fields = [np.asarray(x)[:, None, :] for x in (success, violation, steps, accepting)]
    gave_up = None if aborted is None else np.asarray(aborted, bool)[:, None, :]
    return EvalResult("Tiny-v0", ("F a",), np.array([finite]), (1, 2), 2, 75,
                      EpisodeTable(fields[0].astype(bool), fields[1].astype(bool), *fields[2:], gave_up))


GOOD = result([[1, 1], [1, 0]], [[0, 0], [0, 1]], [[4, 6], [8, 3]], [[0, 0], [0, 0]])
NEVER = result([[0, 0], [0, 0]], [[1, 0], [0, 0]], [[2, 75], [75, 75]], [[0, 0], [0, 0]])
LOOPS = result([[0, 0], [0, 0]], [[0, 1], [0, 0]], [[75] * 2] * 2, [[4, 9], [2, 6]], finite=False,
               aborted=[[0, 0], [0, 1]])


def test_markdown_rows_env_by_suite_and_columns_method_by_metric():
    results = [SuiteResult("Tiny-v0", "finite/a", "oracle", GOOD),
               SuiteResult("Tiny-v0", "finite/a", "random", NEVER),
               SuiteResult("Tiny-v0", "infinite/b", "random", LOOPS)]
    finite, infinite = markdown_tables(results).strip().split("\n\n")
    assert finite.splitlines() == [
        ("| env | suite | oracle eta_s | oracle eta_v | oracle mu | oracle eta_a | random eta_s "
         "| random eta_v | random mu | random eta_a |"),
        "|---|---|---|---|---|---|---|---|---|---|",
        ("| Tiny-v0 | finite/a | 0.75±0.25 | 0.25±0.25 | 6.50±1.50 | 0.00±0.00 | 0.00±0.00 "
         "| 0.25±0.25 | - | 0.00±0.00 |"),
    ]
    # seed 2 gave its second episode up: abort rate 0.5 there, and mu_acc averages seed 2's first only
    assert infinite.splitlines()[2] == "| Tiny-v0 | infinite/b | 3.00±1.00 | 0.25±0.25 | 0.25±0.25 |"


def test_json_holds_config_versions_tables_and_null_for_nan(tmp_path):
    path = write_json(tmp_path / "eval.json", [SuiteResult("Tiny-v0", "s", "random", NEVER)],
                      {"policy": "random"})
    data = json.loads(path.read_text())  # strict JSON: no NaN tokens
    assert "NaN" not in path.read_text()
    assert data["config"] == {"policy": "random"} and "jax" in data["versions"]
    entry = data["results"][0]
    assert entry["seeds"] == [1, 2] and entry["episodes"]["steps"] == [[[2, 75]], [[75, 75]]]
    assert entry["summary"]["groups"]["s"]["mu_mean"] is None
    assert entry["summary"]["groups"]["s"]["eta_v_mean"] == 0.25
    assert entry["per_seed"]["eta_a"] == [[0.0], [0.0]]


def test_plots_are_written(tmp_path):
    results = [SuiteResult("Tiny-v0", f"letter/complexity/reach_only/seq{n}_disj{d}", "oracle", GOOD)
               for n in (2, 4) for d in (0, 1)]
    assert plot_complexity(results, tmp_path / "c.png").stat().st_size > 10_000
    assert plot_complexity(results[:0], tmp_path / "none.png") is None
    letters = np.full((2, 5, 5), -1)
    letters[:, 0, 1] = 0
    paths = [np.array([[0, 0], [0, 1]]), np.array([[0, 0], [4, 0], [4, 4]])]  # second one wraps
    out = plot_trajectories(letters, paths, ["F a", "G !a"], ("a",), tmp_path / "t.png")
    assert out.stat().st_size > 5_000
