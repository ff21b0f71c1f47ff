"""Metric definitions on hand-made episode tables."""

import math

import numpy as np
import pytest

from specrl_jax.eval.metrics import EpisodeTable, format_mean_std, per_seed_metrics, summarize


def table(success, violation, steps, accepting) -> EpisodeTable:
    """One seed, one spec from per-episode lists; returns fields of shape [1, 1, E]."""
    return EpisodeTable(*(np.asarray(x)[None, None] for x in (success, violation, steps, accepting)))


def test_rates_and_steps_over_successful_episodes_only():
    # 5 episodes: 2 successes (4 and 8 steps), 1 violation (2 steps), 2 timeouts (75 steps)
    m = per_seed_metrics(table([1, 0, 1, 0, 0], [0, 1, 0, 0, 0], [4, 2, 8, 75, 75], [0] * 5))
    assert m["eta_s"][0, 0] == pytest.approx(0.4)
    assert m["eta_v"][0, 0] == pytest.approx(0.2)
    assert m["eta_o"][0, 0] == pytest.approx(0.4)
    assert m["mu"][0, 0] == pytest.approx(6.0)
    assert m["eta_a"][0, 0] == 0.0  # no aborted field: nothing was given up


def test_abort_rate_counts_given_up_episodes_within_other():
    # 4 episodes: success, violation, aborted, timeout; 2 seeds, the second aborts twice
    success = np.array([[[1, 0, 0, 0]], [[1, 0, 0, 0]]], bool)
    violation = np.array([[[0, 1, 0, 0]], [[0, 0, 0, 0]]], bool)
    aborted = np.array([[[0, 0, 1, 0]], [[0, 1, 1, 0]]], bool)
    steps = np.full(success.shape, 75)
    m = per_seed_metrics(EpisodeTable(success, violation, steps, np.zeros_like(steps), aborted))
    np.testing.assert_allclose(m["eta_a"], [[0.25], [0.5]])
    np.testing.assert_allclose(m["eta_o"], [[0.5], [0.75]])  # aborts are part of the other outcomes
    s = summarize(m)["specs"]["0"]
    assert s["eta_a_mean"] == pytest.approx(0.375) and s["eta_a_std"] == pytest.approx(0.125)


def test_accepting_visits_over_non_violating_episodes_only():
    m = per_seed_metrics(table([0, 0, 0, 0], [0, 1, 0, 1], [75, 10, 75, 3], [6, 2, 3, 9]))
    assert m["mu_acc"][0, 0] == pytest.approx(4.5)  # (6 + 3) / 2; the violators' 2 and 9 are out
    assert m["eta_o"][0, 0] == pytest.approx(0.5)


def test_no_success_gives_nan_mu_printed_as_dash():
    m = per_seed_metrics(table([0, 0], [1, 0], [3, 75], [0, 0]))
    assert math.isnan(m["mu"][0, 0])
    all_violate = per_seed_metrics(table([0, 0], [1, 1], [3, 5], [1, 1]))
    assert math.isnan(all_violate["mu_acc"][0, 0])
    summary = summarize(m)["specs"]["0"]
    assert math.isnan(summary["mu_mean"])
    assert format_mean_std(summary["mu_mean"], summary["mu_std"]) == "-"
    assert format_mean_std(0.5, 0.125) == "0.50±0.12"


def test_mean_and_std_over_seeds_per_spec_and_per_suite():
    # 2 seeds x 2 specs x 2 episodes
    success = np.array([[[1, 1], [1, 0]], [[1, 0], [0, 0]]], bool)
    violation = np.array([[[0, 0], [0, 1]], [[0, 1], [0, 0]]], bool)
    steps = np.array([[[2, 4], [10, 3]], [[6, 9], [75, 75]]])
    m = per_seed_metrics(EpisodeTable(success, violation, steps, np.zeros_like(steps)))
    np.testing.assert_allclose(m["eta_s"], [[1.0, 0.5], [0.5, 0.0]])
    np.testing.assert_allclose(m["mu"], [[3.0, 10.0], [6.0, np.nan]])
    s = summarize(m, {"suite": [0, 1]})
    assert s["specs"]["0"]["eta_s_mean"] == pytest.approx(0.75)
    assert s["specs"]["0"]["eta_s_std"] == pytest.approx(0.25)  # population std over 2 seeds
    assert s["specs"]["1"]["mu_mean"] == pytest.approx(10.0)  # the seed without success is skipped
    assert s["specs"]["1"]["mu_std"] == pytest.approx(0.0)
    # suite: per seed, mean over specs (NaN-skipping), then over seeds
    assert s["groups"]["suite"]["eta_s_mean"] == pytest.approx((0.75 + 0.25) / 2)
    assert s["groups"]["suite"]["mu_mean"] == pytest.approx((6.5 + 6.0) / 2)
    assert s["groups"]["suite"]["mu_std"] == pytest.approx(0.25)


def test_corrupt_tables_are_rejected():
    with pytest.raises(ValueError, match="both succeed and violate"):
        per_seed_metrics(table([1], [1], [3], [0]))
    with pytest.raises(ValueError, match="empty"):
        summarize(per_seed_metrics(table([1], [0], [3], [0])), {"suite": []})
