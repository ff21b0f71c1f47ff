"""Do two training runs of the same cell learn alike? Compares their training success per seed
(`success_rate_seeds` of each update in a run's `metrics.jsonl`, matched by `update`) over whole
windows of updates, up to the shorter run: for each window, each run's mean over seeds, its
seeds' standard deviation, and whether the means differ by at most two standard errors of their
difference (`2 sqrt(s_a^2 / n_a + s_b^2 / n_b)`, seeds as independent samples: what two runs
with other seeds give about 95% of the time). Windows share seeds, so they are not independent
checks. Prints one JSON row (`benchmarks/harness.py`; appended to `--out`) and, with `--plot`,
draws both runs' curves (mean and every seed).

    python benchmarks/lab/curve_agreement.py \\
        benchmarks/results/pointltl0vision64_deepltl_partial_metrics_h200.jsonl \\
        specrl_jax/benchmark/results/PointLTL0Vision-v0__deepltl/metrics.jsonl \\
        --labels float32 bfloat16 --window 20
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness


def success_per_seed(path: str) -> dict[int, list[float]]:
    """{update: training success rate of each seed} of the run at `path` (a later row of the
    same update, after a resume, replaces the earlier)."""
    with open(path) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    if not rows or any("success_rate_seeds" not in r or "update" not in r for r in rows):
        raise ValueError(f"{path}: rows without `update` and `success_rate_seeds`; pass a "
                         "training run's metrics.jsonl")
    return {int(r["update"]): r["success_rate_seeds"] for r in rows}


def aligned(a: dict[int, list[float]], b: dict[int, list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """[updates, seeds] arrays of both runs over the updates 1..N both have."""
    n = 0
    while n + 1 in a and n + 1 in b:
        n += 1
    if n == 0:
        raise ValueError("the runs share no updates from update 1")
    return (np.array([a[u] for u in range(1, n + 1)], dtype=float),
            np.array([b[u] for u in range(1, n + 1)], dtype=float))


def windows(a: np.ndarray, b: np.ndarray, window: int) -> list[dict]:
    """Per whole window of `window` updates: the means over seeds, the seeds' standard
    deviations (ddof 1), the difference's standard error and whether the means are within two."""
    if window < 1 or window > len(a):
        raise ValueError(f"--window {window}: choose 1 to {len(a)} updates (the shorter run)")
    out = []
    for lo in range(0, len(a) - window + 1, window):
        seeds_a, seeds_b = a[lo:lo + window].mean(0), b[lo:lo + window].mean(0)
        sd_a, sd_b = seeds_a.std(ddof=1), seeds_b.std(ddof=1)
        se = float(np.sqrt(sd_a**2 / len(seeds_a) + sd_b**2 / len(seeds_b)))
        gap = abs(seeds_a.mean() - seeds_b.mean())
        out.append({"updates": [lo + 1, lo + window],
                    "mean": [round(seeds_a.mean(), 3), round(seeds_b.mean(), 3)],
                    "seed_std": [round(sd_a, 3), round(sd_b, 3)], "se": round(se, 3),
                    "within_two_se": bool(gap <= 2 * se)})
    return out


def plot(a: np.ndarray, b: np.ndarray, labels: list[str], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for curves, label, colour in ((a, labels[0], "tab:blue"), (b, labels[1], "tab:orange")):
        updates = np.arange(1, len(curves) + 1)
        ax.plot(updates, curves, color=colour, alpha=0.2, linewidth=0.8)
        ax.plot(updates, curves.mean(1), color=colour, linewidth=2, label=f"{label} (mean)")
    ax.set_xlabel("update")
    ax.set_ylabel("training success rate")
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs=2, help="two metrics.jsonl files")
    parser.add_argument("--labels", nargs=2, default=["first", "second"])
    parser.add_argument("--window", type=int, default=20, help="updates per window")
    parser.add_argument("--plot", default=None, help="write the curves to this PNG")
    parser.add_argument("--out", default=None, help="append the JSON row to this file")
    args = parser.parse_args()
    a, b = aligned(success_per_seed(args.runs[0]), success_per_seed(args.runs[1]))
    rows = windows(a, b, args.window)
    gaps = [abs(r["mean"][0] - r["mean"][1]) for r in rows]
    above = sum(r["mean"][1] > r["mean"][0] for r in rows)
    value = (f"{args.labels[0]} against {args.labels[1]} over updates 1-{rows[-1]['updates'][1]}: "
             f"the means over seeds {min(gaps):.2f}-{max(gaps):.2f} apart per window of "
             f"{args.window} updates, within two standard errors in "
             f"{sum(r['within_two_se'] for r in rows)} of {len(rows)} windows; "
             f"{args.labels[1]} above in {above}")
    if args.plot:
        plot(a, b, args.labels, args.plot)
    harness.emit(harness.row("Training success of two runs per window of updates", value,
                             runs=args.runs, labels=args.labels, windows=rows), args.out)


if __name__ == "__main__":
    main()
