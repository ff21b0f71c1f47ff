"""Reports: a JSON file with everything, Markdown tables in the paper's layout, and plots.

A report is built from `SuiteResult`s, one per (env, suite, method). Tables have one row per
env x suite and, per method, the columns of the paper: `eta_s`, `eta_v`, `mu` for finite-horizon
suites and `mu_acc`, `eta_v` for infinite-horizon ones, then the abort rate `eta_a` (episodes the
policy gave up, as the GenZ-LTL reference prints its unreachable count), each as `mean±std` over
seeds ("-" where no episode qualified, e.g. `mu` without any success).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import platform
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from specrl_jax.eval.evaluate import EvalResult
from specrl_jax.eval.metrics import METRICS, format_mean_std

FINITE_COLUMNS = ("eta_s", "eta_v", "mu", "eta_a")
INFINITE_COLUMNS = ("mu_acc", "eta_v", "eta_a")
COMPLEXITY = re.compile(r"(reach_only|reach_avoid)/seq(\d+)_disj(\d+)$")


@dataclasses.dataclass(frozen=True)
class SuiteResult:
    """One suite evaluated with one method on one env."""

    env_id: str
    suite: str
    method: str
    result: EvalResult

    @property
    def is_finite(self) -> bool:
        return bool(np.all(self.result.is_finite))

    def summary(self) -> dict[str, Any]:
        """Per spec and for the whole suite: `metric_mean` / `metric_std` over seeds."""
        return self.result.summary({self.suite: list(range(len(self.result.spec_names)))})

    def suite_metrics(self) -> dict[str, float]:
        return self.summary()["groups"][self.suite]


def versions() -> dict[str, str]:
    """Versions of the packages and the device that produced a result."""
    import flax
    import jax
    import jaxlib

    import specrl_jax

    device = jax.devices()[0]
    return {
        "specrl_jax": specrl_jax.__version__,
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "flax": flax.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "device": f"{device.platform}:{getattr(device, 'device_kind', '')}",
    }


def _finite_or_none(x: Any) -> Any:
    """JSON has no NaN: NaN (nothing to average) becomes null."""
    if isinstance(x, dict):
        return {k: _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite_or_none(v) for v in x]
    if isinstance(x, float) and math.isnan(x):
        return None
    return x


def to_dict(results: Sequence[SuiteResult], config: dict[str, Any]) -> dict[str, Any]:
    """Everything about a run: config, versions, seeds, per-episode tables, per-seed metrics
    and mean/std per spec and per suite."""
    entries = []
    for item in results:
        r = item.result
        per_seed = r.per_seed()
        entries.append({
            "env": item.env_id,
            "suite": item.suite,
            "method": item.method,
            "specs": list(r.spec_names),
            "is_finite": r.is_finite.tolist(),
            "seeds": list(r.seeds),
            "episodes_per_seed": r.episodes_per_seed,
            "horizon": r.horizon,
            "summary": item.summary(),
            "per_seed": {m: v.tolist() for m, v in per_seed.items()},
            "episodes": {name: np.asarray(value).tolist()
                         for name, value in r.table._asdict().items()},
        })
    return _finite_or_none({"config": config, "versions": versions(), "results": entries})


def write_json(path: str | Path, results: Sequence[SuiteResult], config: dict[str, Any]) -> Path:
    path = Path(path)
    path.write_text(json.dumps(to_dict(results, config), indent=1))
    return path


def markdown_tables(results: Sequence[SuiteResult], digits: int = 2) -> str:
    """One table for finite-horizon suites and one for infinite ones (whichever are present):
    rows env x suite, columns method x metric, cells `mean±std`."""
    parts = []
    for finite, columns in ((True, FINITE_COLUMNS), (False, INFINITE_COLUMNS)):
        chosen = [r for r in results if r.is_finite == finite]
        if any(r.result.table.num_accepting_original is not None for r in chosen) and not finite:
            columns = columns[:1] + ("mu_acc_original",) + columns[1:]
        if chosen:
            parts.append(_table(chosen, columns, digits))
    return "\n\n".join(parts) + "\n"


def _table(results: Sequence[SuiteResult], columns: Sequence[str], digits: int) -> str:
    methods = list(dict.fromkeys(r.method for r in results))
    rows = list(dict.fromkeys((r.env_id, r.suite) for r in results))
    cells = {(r.env_id, r.suite, r.method): r.suite_metrics() for r in results}
    header = ["env", "suite"] + [f"{m} {c}" for m in methods for c in columns]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for env_id, suite in rows:
        row = [env_id, suite]
        for method in methods:
            stats = cells.get((env_id, suite, method))
            for c in columns:
                row.append("-" if stats is None else format_mean_std(
                    stats.get(f"{c}_mean", math.nan), stats.get(f"{c}_std", math.nan), digits))
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def plot_complexity(results: Sequence[SuiteResult], path: str | Path) -> Path | None:
    """`eta_s` and `mu` versus sequence length, one line per (method, disjunctions), one panel
    column per kind (reach-only, reach-avoid). None when no complexity suite is present."""
    points: dict[tuple[str, str, int], list[tuple[int, dict[str, float]]]] = {}
    for r in results:
        match = COMPLEXITY.search(r.suite)
        if match:
            kind, length, disj = match.group(1), int(match.group(2)), int(match.group(3))
            points.setdefault((kind, r.method, disj), []).append((length, r.suite_metrics()))
    if not points:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = sorted({k for k, _, _ in points})
    fig, axes = plt.subplots(2, len(kinds), figsize=(5 * len(kinds), 7), squeeze=False)
    for col, kind in enumerate(kinds):
        for (k, method, disj), series in sorted(points.items()):
            if k != kind:
                continue
            series.sort(key=lambda p: p[0])
            x = [length for length, _ in series]
            for row, metric in enumerate(("eta_s", "mu")):
                mean = np.array([s[f"{metric}_mean"] for _, s in series], float)
                std = np.array([s[f"{metric}_std"] for _, s in series], float)
                axes[row, col].errorbar(x, mean, yerr=std, marker="o", capsize=3,
                                        label=f"{method}, {disj} disj.")
        lengths = sorted({length for (k, _, _), series in points.items() if k == kind
                          for length, _ in series})
        for row in range(2):
            axes[row, col].set_xticks(lengths)
        axes[0, col].set_ylim(-0.02, 1.05)
        axes[0, col].set_title(kind.replace("_", "-"))
        axes[0, col].set_ylabel("success rate eta_s")
        axes[1, col].set_ylabel("steps to success mu")
        axes[1, col].set_xlabel("sequence length")
        axes[0, col].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def plot_trajectories(letters: np.ndarray, paths: Sequence[np.ndarray], titles: Sequence[str],
                      propositions: Sequence[str], path: str | Path) -> Path:
    """Draw episodes on their LetterWorld maps.

    Args:
        letters: int[B, N, N] per episode, -1 empty, else the letter index.
        paths: per episode int[T_b, 2] agent cells (row, col), the start first.
        titles: per episode, e.g. the formula and the outcome.
        propositions: letter names.
        path: the PNG file to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    count = len(paths)
    fig, axes = plt.subplots(1, count, figsize=(3.6 * count, 4.0), squeeze=False)
    for ax, grid, cells, title in zip(axes[0], letters, paths, titles):
        n = grid.shape[0]
        ax.set_xlim(-0.5, n - 0.5)
        ax.set_ylim(n - 0.5, -0.5)
        ax.set_xticks(np.arange(-0.5, n, 1), labels=[])
        ax.set_yticks(np.arange(-0.5, n, 1), labels=[])
        ax.grid(color="0.6", linewidth=0.5)
        for (r, c), letter in np.ndenumerate(grid):
            if letter >= 0:
                ax.add_patch(plt.Rectangle((c - 0.5, r - 0.5), 1, 1, color="0.85"))
                ax.text(c, r, propositions[letter], ha="center", va="center", fontsize=12)
        cells = np.asarray(cells, float)
        for start, end in itertools.pairwise(cells):
            move = end - start
            if np.abs(move).max() > 1:  # wrapped across the torus: half a step off each edge
                move = -np.sign(move)
                segments = [(start, start + move / 2), (end - move / 2, end)]
            else:
                segments = [(start, end)]
            for a, b in segments:
                ax.plot([a[1], b[1]], [a[0], b[0]], color="tab:green", linewidth=2, alpha=0.8)
        ax.plot(cells[0, 1], cells[0, 0], "o", color="tab:green", markersize=9)
        ax.plot(cells[-1, 1], cells[-1, 0], "X", color="tab:red", markersize=9)
        ax.set_title(title, fontsize=8, wrap=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
