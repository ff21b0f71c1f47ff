"""Plot training curves of several runs side by side: one panel per metric, one line per run,
against env steps per seed (the `metrics.jsonl` a run directory or `benchmarks/results/` holds).

    python benchmarks/compare_curves.py \
        --run "no pretraining=benchmarks/results/letterltl0_ltl2action_curriculum_metrics.jsonl" \
        --run "pretrained encoder=benchmarks/results/letterltl0_ltl2action_pretrained_10M_metrics.jsonl" \
        --keys success_rate curriculum_stage --out /tmp/curves.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def labelled_path(text: str) -> tuple[str, Path]:
    """argparse type: `LABEL=PATH` of a metrics.jsonl (or of a run directory holding one)."""
    label, sep, path = text.partition("=")
    if not sep or not label or not path:
        raise argparse.ArgumentTypeError(f"expected LABEL=PATH, got {text!r}")
    path = Path(path)
    if path.is_dir():
        path = path / "metrics.jsonl"
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"no metrics file at {path}")
    return label, path


def read_rows(path: Path) -> list[dict[str, float]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=labelled_path, action="append", required=True,
                        metavar="LABEL=PATH", help="a run's metrics.jsonl (repeatable)")
    parser.add_argument("--keys", nargs="+", default=["success_rate", "violation_rate"],
                        help="metrics to plot, one panel each (default: success and violation rates)")
    parser.add_argument("--title", default=None)
    parser.add_argument("--out", required=True, help="the figure (.png)")
    args = parser.parse_args()
    runs = [(label, read_rows(path)) for label, path in args.run]
    for key in args.keys:
        if not any(rows and key in rows[0] for _, rows in runs):
            parser.error(f"no run has the metric {key!r}; the first run has: {', '.join(runs[0][1][0])}")
    fig, axes = plt.subplots(1, len(args.keys), figsize=(5 * len(args.keys), 3.5), squeeze=False)
    for ax, key in zip(axes[0], args.keys):
        for label, rows in runs:
            if rows and key in rows[0]:
                ax.plot([r["env_steps"] / 1e6 for r in rows], [r[key] for r in rows], label=label)
        ax.set_xlabel("env steps per seed (millions)")
        ax.set_ylabel(key)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    if args.title:
        fig.suptitle(args.title)
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
