"""Do two training runs of the same cell learn alike? Compares their training success per seed
(`success_rate_seeds` of each update in a run's `metrics.jsonl`) over windows of updates, up to
the shorter run: for each window, each run's mean over seeds and the spread between its seeds.
A difference of the means inside the seeds' spread is what a rerun with other seeds gives; one
outside it is a change in learning. Prints one JSON row (`benchmarks/harness.py`; appended to
`--out`) and, with `--plot`, draws both runs' curves (mean and every seed).

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


def success_per_seed(path: str) -> np.ndarray:
    """[updates, seeds] training success rate of each update of the run at `path`."""
    with open(path) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    if not rows or "success_rate_seeds" not in rows[0]:
        raise ValueError(f"{path}: no `success_rate_seeds` in its rows; pass a training run's "
                         "metrics.jsonl")
    return np.array([r["success_rate_seeds"] for r in rows], dtype=float)


def windows(a: np.ndarray, b: np.ndarray, window: int) -> list[dict]:
    """Per window of `window` updates (up to the shorter run): the means over seeds, the seeds'
    standard deviation of each run, and whether the means differ by less than the larger one."""
    updates = min(len(a), len(b))
    out = []
    for lo in range(0, updates, window):
        hi = min(lo + window, updates)
        seeds_a, seeds_b = a[lo:hi].mean(0), b[lo:hi].mean(0)
        spread = max(seeds_a.std(), seeds_b.std())
        out.append({"updates": [lo + 1, hi], "mean": [round(seeds_a.mean(), 3), round(seeds_b.mean(), 3)],
                    "seed_std": [round(seeds_a.std(), 3), round(seeds_b.std(), 3)],
                    "within_spread": bool(abs(seeds_a.mean() - seeds_b.mean()) <= spread)})
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
    a, b = success_per_seed(args.runs[0]), success_per_seed(args.runs[1])
    rows = windows(a, b, args.window)
    agree = sum(r["within_spread"] for r in rows)
    value = (f"{args.labels[0]} against {args.labels[1]}: the means over seeds differ by "
             f"{min(abs(r['mean'][0] - r['mean'][1]) for r in rows):.2f}-"
             f"{max(abs(r['mean'][0] - r['mean'][1]) for r in rows):.2f} per window of "
             f"{args.window} updates, within the seeds' spread in {agree} of {len(rows)} windows "
             f"(updates 1-{min(len(a), len(b))})")
    if args.plot:
        plot(a, b, args.labels, args.plot)
    harness.emit(harness.row("Training success of two runs per window of updates", value,
                             runs=args.runs, labels=args.labels, windows=rows), args.out)


if __name__ == "__main__":
    main()
