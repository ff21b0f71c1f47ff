"""Render the results page, `docs/results.md`, and its figures (`docs/figures/`) from data only:
the results store (our reproductions, per world and suite, mean ± std over seeds, beside the
paper's published numbers from `paper_tables.yaml`) and `data/measurements.yaml` (the current
figure of every headline measurement, one table per section). Nothing on the page is typed by
hand, and rendering is deterministic: the same store and data give the same files.

    specrl-jax report [--store DIR] [--out docs/results.md]
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from specrl_jax.benchmark import grid, paper
from specrl_jax.benchmark.grid import Cell
from specrl_jax.benchmark.store import Store, suite_metric, suite_seeds

MEASUREMENTS = Path(__file__).resolve().parent / "data" / "measurements.yaml"
METHOD_NAMES = {"genz": "GenZ-LTL", "deepltl": "DeepLTL", "ltl2action": "LTL2Action",
                "gcrl": "GCRL-LTL", "rad": "RAD-Embeddings"}
VARIANT_NAMES = {"bootcamp": "from the LTLBootcamp encoder", "coordinator": "+ coordinator"}
FINITE = (("eta_s", "η_s"), ("eta_v", "η_v"), ("mu", "μ steps"))
INFINITE = (("mu_acc", "μ_acc"), ("eta_v", "η_v"), ("eta_a", "η_a"))
MEASUREMENT_COLUMNS = ("figure", "value", "device", "batch", "date", "command")
#: the paper's figure (a): robot dynamics x observation modality
DYNAMICS = (("Point", "PointLTL0-v0", "PointLTL0Vision-v0"),
            ("Car", "CarLTL0-v0", "CarLTL0Vision-v0"),
            ("Ant", "AntLTL0-v0", "AntLTL0Vision-v0"))
#: the paper's figure (b): partial view, moving zones, the arm's two modes
SETTINGS = (("LetterWorld partial view", "LetterLTL0-v0.partial", "letter/finite/ind"),
            ("Zone level 1 (moving)", "PointLTL1-v0", "zone/finite/ind"),
            ("Zone level 2 (moving)", "PointLTL2-v0", "zone/finite/ind"),
            ("Arm, grippers only", "PandaLTLReach0Joints-v0", "arm_grippers/finite/ind"),
            ("Arm, grippers and arm", "PandaLTLReach1Joints-v0", "arm_grippers_arm/finite/ind"))


def method_label(c: Cell) -> str:
    name = METHOD_NAMES.get(c.method, c.method)
    if c.variant:
        name += f" ({VARIANT_NAMES.get(c.variant, c.variant)})" if c.variant != "coordinator" \
            else f" {VARIANT_NAMES['coordinator']}"
    return name


def _fmt(mean: float | None, std: float | None, digits: int = 2) -> str:
    if mean is None:
        return "-"
    return f"{mean:.{digits}f} ± {std:.{digits}f}" if std is not None else f"{mean:.{digits}f}"


def _digits(metric: str) -> int:
    return 1 if metric in ("mu", "mu_acc") else 2


def _cells_by_env(store: Store) -> dict[str, list[tuple[Cell, dict[str, Any]]]]:
    """Grid cells the store holds, grouped by env ID, in grid order."""
    out: dict[str, list[tuple[Cell, dict[str, Any]]]] = {}
    for c in grid.GRID:
        record = store.read(c)
        if record is not None:
            out.setdefault(c.env_id, []).append((c, record))
    return out


def _state_note(c: Cell, record: dict[str, Any], store: Store) -> str:
    if store.state(c) == "done":
        return ""
    return f" **(partial: {suite_seeds(record)}/{c.seeds} seeds)**"


def suite_table(env_id: str, suite: str, rows: Sequence[tuple[Cell, dict[str, Any]]],
                store: Store) -> list[str]:
    """One suite's table: our mean ± std over seeds per method, the paper's beside it."""
    finite = "/finite/" in suite
    columns = FINITE if finite else INFINITE
    quoted = [m for m, _ in columns
              if any(paper.lookup(env_id, suite, c.method, m) for c, _ in rows)]
    head = ["method", *(label for _, label in columns),
            *(f"paper {dict(columns)[m]}" for m in quoted), "seeds x episodes, horizon"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c, record in rows:
        entry = record.get("suites", {}).get(suite)
        if entry is None:
            continue
        ours = [_fmt(*suite_metric(entry, m), digits=_digits(m)) for m, _ in columns]
        theirs = []
        for m in quoted:
            number = paper.lookup(env_id, suite, c.method, m)
            theirs.append(number.text() if number else "-")
        size = f"{len(entry['seeds'])} x {entry['episodes_per_seed']}, {entry['horizon']:,}"
        lines.append("| " + " | ".join([method_label(c) + _state_note(c, record, store),
                                         *ours, *theirs, size]) + " |")
    return lines if len(lines) > 2 else []


def grid_table(store: Store) -> list[str]:
    """One row per cell with results; the cells not yet run as one line per world."""
    lines = [("| cell | step | state | seeds evaluated | env steps per seed | device | "
              "training s | evaluation s |"), "|---|---|---|---|---|---|---|---|"]
    missing: dict[str, list[str]] = {}
    for c in grid.GRID:
        record = store.read(c)
        if record is None:
            missing.setdefault(f"`{c.env_id}` (step {c.step})", []).append(c.name.split("/", 1)[1])
            continue
        steps = record.get("training", {}).get("env_steps_per_seed")
        wall = record.get("wall_s", {})
        lines.append(
            f"| `{c.name}` | {c.step} | {store.state(c)} | {suite_seeds(record)}/{c.seeds} | "
            f"{f'{steps:,}' if steps else '-'} | {record.get('device') or '-'} | "
            f"{_fmt(wall.get('train'), None, 0)} | {_fmt(wall.get('eval'), None, 0)} |")
    if missing:
        lines += ["", "Not yet run: " + "; ".join(f"{world}: {', '.join(methods)}"
                                               for world, methods in missing.items()) + "."]
    return lines


def measurement_sections(path: str | Path = MEASUREMENTS) -> list[str]:
    """One table per `section` of the measurements file, sections in order of appearance."""
    path = Path(path)
    if not path.exists():
        return []
    entries = yaml.safe_load(path.read_text()) or []
    sections: dict[str, list[dict[str, Any]]] = {}
    for entry in entries:
        sections.setdefault(str(entry.get("section", "Other")), []).append(entry)
    lines: list[str] = []
    for name, rows in sections.items():
        lines += [f"### {name}", "", "| " + " | ".join(MEASUREMENT_COLUMNS) + " |",
                  "|" + "---|" * len(MEASUREMENT_COLUMNS)]
        for row in rows:
            cells = []
            for key in MEASUREMENT_COLUMNS:
                value = "" if row.get(key) is None else str(row.get(key)).replace("|", "\\|")
                value = " ".join(value.split())
                cells.append(f"`{value}`" if key == "command" and value else value)
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines


# ---------------------------------------------------------------------------------------------
# Figures


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"svg.hashsalt": "specrl_jax", "figure.dpi": 100})
    return plt


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, metadata={"Software": None}, bbox_inches="tight")
    _pyplot().close(fig)
    return path


def _bars(ax: Any, env_id: str, suite: str, store: Store, title: str) -> None:
    """Success and violation of the five methods on one world and suite; a missing cell is
    drawn as a 'missing' label, a partial one marked."""
    import numpy as np

    # per method, the plain cell, else its one variant (the multi-agent coordinator cells)
    names = sorted((c for c in grid.GRID if c.env_id == env_id and c.variant != "bootcamp"),
                   key=lambda c: bool(c.variant))
    methods = grid.COORDINATOR_METHODS if any(c.variant == "coordinator" for c in names) \
        else grid.METHODS
    x = np.arange(len(methods))
    ax.set_title(title, fontsize=9)
    ax.set_xticks(x, [METHOD_NAMES[m].split("-")[0] for m in methods], fontsize=7, rotation=30)
    ax.set_xlim(-0.6, len(methods) - 0.4)
    ax.set_ylim(0, 1.05)
    for i, method in enumerate(methods):
        c = next((c for c in names if c.method == method), None)
        record = store.read(c) if c is not None else None
        entry = (record or {}).get("suites", {}).get(suite)
        if entry is None:
            ax.text(i, 0.5, "missing", rotation=90, ha="center", va="center", fontsize=7,
                    color="0.5")
            continue
        s, s_std = suite_metric(entry, "eta_s")
        v, v_std = suite_metric(entry, "eta_v")
        ax.bar(i - 0.2, s or 0.0, 0.4, yerr=s_std or 0.0, color=COLOURS["success"])
        ax.bar(i + 0.2, v or 0.0, 0.4, yerr=v_std or 0.0, color=COLOURS["violation"])
        if store.state(c) != "done":
            ax.text(i, 1.0, "partial", ha="center", fontsize=6)


COLOURS = {"success": "tab:green", "violation": "tab:red"}


def _legend(ax: Any) -> None:
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color=c, label=k) for k, c in COLOURS.items()], fontsize=7,
              loc="upper right")


def world_figure(env_id: str, suites: Sequence[str], store: Store, path: Path) -> Path:
    plt = _pyplot()
    finite = [s for s in suites if "/finite/" in s]
    fig, axes = plt.subplots(1, len(finite), figsize=(3.2 * len(finite), 2.8), squeeze=False,
                             layout="constrained")
    for ax, suite in zip(axes[0], finite):
        _bars(ax, env_id, suite, store, f"{env_id} {suite.split('/')[-1].upper()}")
    axes[0][0].set_ylabel("rate (mean ± std over seeds)", fontsize=8)
    _legend(axes[0][0])
    return _save(fig, path)


def read_curve(path: Path) -> list[dict[str, Any]]:
    """A training curve's rows (`metrics.jsonl`: one per PPO update, seed means)."""
    import json

    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def curves_figure(rows: Sequence[tuple[Cell, dict[str, Any]]], store: Store, path: Path,
                  keys: Sequence[str] = ("success_rate", "violation_rate")) -> Path | None:
    """Training curves of a world's cells side by side: one panel per metric, one line per
    cell, against env steps per seed (None when no cell has a curve)."""
    curves = [(c, read_curve(store.curve_path(c))) for c, _ in rows
              if store.curve_path(c).exists()]
    if not curves:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.2), squeeze=False,
                             layout="constrained")
    for ax, key in zip(axes[0], keys):
        for c, curve in curves:
            points = [(r["env_steps"] / 1e6, r[key]) for r in curve
                      if r.get(key) is not None and "env_steps" in r]
            if points:
                ax.plot(*zip(*points), label=method_label(c), linewidth=1)
        ax.set_xlabel("env steps per seed (millions)", fontsize=8)
        ax.set_ylabel(f"training {key.replace('_', ' ')} (seed mean)", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    return _save(fig, path)


ZONE_COLOURS = {"green": "#2ca02c", "yellow": "#e6c200", "blue": "#1f5fd6", "magenta": "#d62fd6"}
OUTCOME_STYLES = {"success": "-", "violation": "--", "timeout": ":"}


def trajectories_figure(env_id: str, store: Store, path: Path) -> Path | None:
    """The paper's trajectory figure: each method's recorded episodes of the trajectory formula
    on the arena, the first episode's zones drawn (every method meets the same layouts); a
    method without recorded episodes is drawn as missing. None when no cell of `env_id` has
    any."""
    from matplotlib.patches import Circle

    cells = [c for c in grid.GRID if c.env_id == env_id and not c.variant]
    found = {c.method: store.read_trajectories(c) for c in cells}
    if not any(found.values()):
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(grid.METHODS), figsize=(3.0 * len(grid.METHODS), 3.2),
                             layout="constrained")
    formula = next(t["formula"] for t in found.values() if t)
    for ax, method in zip(axes, grid.METHODS):
        ax.set_title(METHOD_NAMES[method], fontsize=9)
        ax.set_xlim(-3.3, 3.3)
        ax.set_ylim(-3.3, 3.3)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        data = found.get(method)
        if not data:
            ax.text(0, 0, "missing", ha="center", va="center", fontsize=8, color="0.5")
            continue
        first = data["episodes"][0]
        for (x, y), colour, radius in zip(first["zone_xy"], first["zone_color"],
                                          first["zone_radius"]):
            ax.add_patch(Circle((x, y), radius, color=ZONE_COLOURS.get(colour, "0.6"), alpha=0.5))
        episode = first
        xy = episode["xy"]
        ax.plot([p[0] for p in xy], [p[1] for p in xy], "k", linewidth=1,
                linestyle=OUTCOME_STYLES.get(episode["outcome"], "-"))
        ax.plot(*xy[0], "ko", markersize=3)
        ax.set_xlabel(episode["outcome"], fontsize=8)
    fig.suptitle(f"{env_id}: {formula} (seed 1, first recorded episode)", fontsize=9)
    return _save(fig, path)


def dynamics_figure(store: Store, path: Path) -> Path:
    """The paper's figure (a): IND success / violation, Point / Car / Ant x LiDAR / image."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(10, 5.5), sharey=True, layout="constrained")
    for j, (robot, lidar, vision) in enumerate(DYNAMICS):
        _bars(axes[0][j], lidar, "zone/finite/ind", store, f"{robot}, LiDAR")
        _bars(axes[1][j], vision, "zone/finite/ind", store, f"{robot}, image")
    _legend(axes[0][0])
    fig.suptitle("IND suite under robot dynamics and observation modality", fontsize=10)
    return _save(fig, path)


def settings_figure(store: Store, path: Path) -> Path:
    """The paper's figure (b): partial view, moving zones, the arm's two modes (IND)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(SETTINGS), figsize=(3.0 * len(SETTINGS), 2.8), sharey=True,
                             layout="constrained")
    for ax, (title, env_id, suite) in zip(axes, SETTINGS):
        _bars(ax, env_id, suite, store, title)
    _legend(axes[0])
    return _save(fig, path)


# ---------------------------------------------------------------------------------------------
# The page


def render(store: Store | str | os.PathLike | None = None,
           out: str | os.PathLike = "docs/results.md",
           figures: str | os.PathLike | None = None,
           measurements: str | os.PathLike = MEASUREMENTS) -> list[Path]:
    """Write the page and its figures; returns the paths written."""
    store = store if isinstance(store, Store) else Store(store)
    out = Path(out)
    fig_dir = Path(figures) if figures is not None else out.parent / "figures"
    rel = os.path.relpath(fig_dir, out.parent).replace(os.sep, "/")
    written: list[Path] = []
    by_env = _cells_by_env(store)
    lines = [
        ("_This page is generated by `specrl-jax report` from the results store "
         "(`specrl_jax/benchmark/results/`), the paper's numbers "
         "(`specrl_jax/benchmark/data/paper_tables.yaml`) and the measurements "
         "(`specrl_jax/benchmark/data/measurements.yaml`); edit those, not this page._"),
        "",
        "# Results",
        "",
        ("Reproductions of the paper's experiments (`specrl-jax reproduce`): per world and suite, "
         "our mean ± std over seeds (each seed evaluated on its own episodes) beside the paper's "
         "published number where the project has it. A cell with fewer seeds than the grid asks "
         "for is marked partial. Then the current figure of every headline measurement. "
         "Departures from the original SpecRLBench and the evidence for each are in "
         "[fidelity.md](fidelity.md)."),
        "",
        "## The experiment grid",
        "",
        "`specrl-jax reproduce --list` shows the same grid with estimated GPU times.",
        "",
        *grid_table(store),
        "",
    ]
    for env_id, rows in by_env.items():
        lines += [f"## {env_id}", ""]
        suites = list(dict.fromkeys(s for c, _ in rows for s in c.suites))
        for suite in suites:
            table = suite_table(env_id, suite, rows, store)
            if table:
                lines += [f"### {suite}", "", *table, ""]
        notes = [f"- {method_label(c)}: {r['params_note']}" for c, r in rows
                 if r.get("params_note")]
        if notes:
            lines += [*notes, ""]
        if any("/finite/" in s for s in suites):
            name = f"success_violation_{grid.file_name(env_id)}.png"
            written.append(world_figure(env_id, suites, store, fig_dir / name))
            lines += [f"![{env_id}: success and violation per method]({rel}/{name})", ""]
        name = f"training_curves_{grid.file_name(env_id)}.png"
        curves = curves_figure(rows, store, fig_dir / name)
        if curves is not None:
            written.append(curves)
            lines += [f"![{env_id}: training curves]({rel}/{name})", ""]
    trajectories = []
    for env_id in ("PointLTL0-v0", "CarLTL0-v0", "AntLTL0-v0"):
        name = f"trajectories_{grid.file_name(env_id)}.png"
        drawn = trajectories_figure(env_id, store, fig_dir / name)
        if drawn is not None:
            written.append(drawn)
            trajectories.append(f"![{env_id}: trajectories]({rel}/{name})")
    written.append(dynamics_figure(store, fig_dir / "robot_dynamics_observation.png"))
    written.append(settings_figure(store, fig_dir / "partial_moving_arm.png"))
    lines += [
        "## The paper's figures, redrawn from the store",
        "",
        ("IND success (green) and violation (red) per method; a cell not yet in the store is "
         "drawn as missing."),
        "",
        f"![robot dynamics and observation modality]({rel}/robot_dynamics_observation.png)",
        "",
        f"![partial view, moving zones, arm modes]({rel}/partial_moving_arm.png)",
        "",
        *(f"{line}\n" for line in trajectories),
        "Where the paper's numbers come from: " + "; ".join(paper.sources()) + ". The paper's "
        "multi-agent table is not quoted in any source the project holds.",
        "",
    ]
    measured = measurement_sections(measurements)
    if measured:
        lines += ["## Measurements", "", *measured]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines).rstrip("\n") + "\n")
    return [out, *written]
