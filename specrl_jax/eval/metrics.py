"""The paper's evaluation metrics, computed on the host from an episode table.

An episode table holds, for every (seed, spec, episode), whether the episode ended in success or
violation, its length in steps (epsilon steps included), its number of accepting transitions and
whether the policy gave it up (aborted). From it, per seed and spec:

- `eta_s`: fraction of episodes that succeed; `eta_v`: fraction that violate;
  `eta_o = 1 - eta_s - eta_v` (timeouts, the world's own terminations, aborted episodes);
  `eta_a`: fraction the policy gave up (aborted; part of `eta_o`; the reference's unreachable rate);
- `mu`: mean steps to success, over successful episodes only (NaN if there is none);
- `mu_acc`: mean accepting visits over non-violating, non-aborted episodes only (NaN if there is
  none), the infinite-horizon metric (GenZ-LTL's protocol, see the reference notes);
- `mu_acc_original` (where tracked): the same mean of the visits counted on the original
  benchmark's automaton (`eval.original_ldba`), beside ours.

Suites aggregate per seed first (the mean over the suite's specs, NaN-skipping for `mu` and
`mu_acc`), then report the mean and the standard deviation (ddof 0) over seeds. A NaN marks "no
episode to average over" and prints as "-", never as 0.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

METRICS = ("eta_s", "eta_v", "eta_o", "eta_a", "mu", "mu_acc")


class EpisodeTable(NamedTuple):
    """Per-episode outcomes; every field has shape `[num_seeds, num_specs, num_episodes]`."""

    success: np.ndarray  # bool
    violation: np.ndarray  # bool
    steps: np.ndarray  # int, episode length in steps (epsilon steps included)
    num_accepting: np.ndarray  # int, accepting transitions taken in the episode
    aborted: np.ndarray | None = None  # bool, the policy gave the episode up (None: never)
    #: int, accepting visits on the original's automaton (eval.original_ldba), -1 where the spec
    #: has none; None when not tracked
    num_accepting_original: np.ndarray | None = None


def _nanmean(x: np.ndarray, axis: int) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices are meant to give NaN
        return np.nanmean(x, axis=axis)


def _nanstd(x: np.ndarray, axis: int) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanstd(x, axis=axis)


def _masked_mean(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean of `values` over the last axis where `mask` holds; NaN where the mask is empty."""
    count = mask.sum(axis=-1)
    total = np.where(mask, values, 0).sum(axis=-1).astype(np.float64)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def per_seed_metrics(table: EpisodeTable) -> dict[str, np.ndarray]:
    """Metrics per seed and spec.

    Args:
        table: the episode table, fields `[num_seeds, num_specs, num_episodes]`.

    Returns:
        `{metric: float64[num_seeds, num_specs]}` for every name in `METRICS`.
    """
    success = np.asarray(table.success, bool)
    violation = np.asarray(table.violation, bool)
    if np.any(success & violation):
        raise ValueError("an episode cannot both succeed and violate; the episode table is corrupt")
    aborted = np.zeros_like(success) if table.aborted is None else np.asarray(table.aborted, bool)
    if np.any(aborted & (success | violation)):
        raise ValueError("an aborted episode cannot succeed or violate; the episode table is corrupt")
    eta_s = success.mean(axis=-1)
    eta_v = violation.mean(axis=-1)
    extra = {}
    if table.num_accepting_original is not None:
        original = np.asarray(table.num_accepting_original)
        extra["mu_acc_original"] = _masked_mean(original, ~violation & ~aborted & (original >= 0))
    return {
        "eta_s": eta_s,
        "eta_v": eta_v,
        "eta_o": 1.0 - eta_s - eta_v,
        "eta_a": aborted.mean(axis=-1),
        "mu": _masked_mean(np.asarray(table.steps), success),
        "mu_acc": _masked_mean(np.asarray(table.num_accepting), ~violation & ~aborted),
        **extra,
    }


def summarize(per_seed: Mapping[str, np.ndarray], spec_groups: Mapping[str, list[int]] | None = None
              ) -> dict[str, dict[str, dict[str, float]]]:
    """Mean and standard deviation over seeds, per spec and per group of specs (a suite).

    Args:
        per_seed: `{metric: float[num_seeds, num_specs]}` from `per_seed_metrics`.
        spec_groups: group name -> indices of its specs; a group's per-seed value is the
            NaN-skipping mean over its specs.

    Returns:
        `{"specs": {str(i): {metric_mean, metric_std...}}, "groups": {name: {...}}}`, floats
        (NaN where nothing was averaged).
    """
    num_specs = next(iter(per_seed.values())).shape[1]
    out: dict[str, dict[str, dict[str, float]]] = {"specs": {}, "groups": {}}
    for i in range(num_specs):
        out["specs"][str(i)] = _mean_std({m: v[:, i] for m, v in per_seed.items()})
    for name, indices in (spec_groups or {}).items():
        if not indices:
            raise ValueError(f"spec group {name!r} is empty")
        out["groups"][name] = _mean_std(
            {m: _nanmean(v[:, list(indices)], axis=1) for m, v in per_seed.items()}
        )
    return out


def _mean_std(values: Mapping[str, np.ndarray]) -> dict[str, float]:
    stats = {}
    for metric, per_seed in values.items():
        stats[f"{metric}_mean"] = float(_nanmean(per_seed[None], axis=1)[0])
        stats[f"{metric}_std"] = float(_nanstd(per_seed[None], axis=1)[0])
    return stats


def format_mean_std(mean: float, std: float, digits: int = 2) -> str:
    """`"0.93±0.02"`; `"-"` when the mean is NaN (nothing to average)."""
    if mean is None or math.isnan(mean):
        return "-"
    return f"{mean:.{digits}f}±{std:.{digits}f}"
