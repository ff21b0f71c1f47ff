"""The results store: one directory per grid cell under `specrl_jax/benchmark/results/`
(`grid.file_name(cell name)`, e.g. `LetterLTL0-v0__genz/`), shipped with the package:

- `cell.json`: the cell's settings, state (`done` / `partial`), versions, device, wall times,
  training summary and, per suite, its version (`specs.suite_version`) and the per-seed metrics
  (`{metric: [seed][spec]}`) with their mean and std over seeds per spec and for the suite;
- `params_seed1.msgpack`: seed 1's trained parameters (no seed axis; `experiment.load_params`
  reads it with `num_seeds=1`);
- `metrics.jsonl`: the training curve (one row per PPO update, seed means);
- `trajectories.json` (Zone LiDAR worlds): a few episodes of the paper's trajectory figure.

A cell is `done` when every suite of its grid entry is evaluated on all its seeds, `partial`
when some of it is, `missing` without a `cell.json`. `Store(root)` reads and writes another
directory (e.g. a scratch store in tests); `scratch/` under a store holds resumable run
directories and is not part of the results.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from specrl_jax import families, specs
from specrl_jax.benchmark import grid
from specrl_jax.benchmark.grid import Cell

DEFAULT_ROOT = Path(__file__).resolve().parent / "results"
CELL_FILE = "cell.json"
PARAMS_FILE = "params_seed1.msgpack"
CURVE_FILE = "metrics.jsonl"
TRAJECTORY_FILE = "trajectories.json"
SCRATCH = "scratch"
STATES = ("done", "partial", "missing")
SCHEMA = 1


def _clean(x: Any) -> Any:
    """JSON without NaN / inf (null instead), tuples as lists, numpy scalars as Python's."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if hasattr(x, "tolist") and not isinstance(x, (str, bytes)):
        return _clean(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def suite_entry(result: Any) -> dict[str, Any]:
    """A `SuiteResult` (or the dict `eval.report.to_dict` writes for one) as the store keeps it:
    settings, per-seed metrics and summary, without the per-episode tables."""
    if not isinstance(result, dict):
        r = result.result
        result = {
            "method": result.method, "specs": list(r.spec_names), "is_finite": r.is_finite.tolist(),
            "seeds": list(r.seeds), "episodes_per_seed": r.episodes_per_seed,
            "horizon": r.horizon, "summary": result.summary(),
            "per_seed": {m: v.tolist() for m, v in r.per_seed().items()},
        }
    keys = ("method", "specs", "is_finite", "seeds", "episodes_per_seed", "horizon", "summary",
            "per_seed")
    return _clean({k: result[k] for k in keys})


def scored_now(suite: str, entry: dict[str, Any]) -> bool:
    """Whether a stored suite entry was scored as `suite` is now (its `suite_version`; entries
    stored before versions were recorded count as current unless the suite's automata take
    epsilon jumps, whose scoring changed since: `specs.suites.INFINITE_SCORING`), and by the
    method's current test-time agent (an entry marked `stale` with the reason, `mark_stale`)."""
    if entry.get("stale"):
        return False
    if "suite_version" in entry:
        return entry["suite_version"] == specs.suite_version(suite)
    return not specs.suite_info(suite).may_jump


def mark_stale(entry: dict[str, Any], reason: str) -> dict[str, Any]:
    """`entry` marked as scored by an earlier test-time agent (`reason`: what changed since, for
    the results page); `reproduce` then runs the suite again."""
    return {**entry, "stale": reason}


class Store:
    """A results store rooted at `root` (default: the package's)."""

    def __init__(self, root: str | os.PathLike | None = None):
        self.root = Path(root) if root is not None else DEFAULT_ROOT

    # --- paths ---------------------------------------------------------------------------
    def cell_dir(self, cell: Cell | str) -> Path:
        return self.root / grid.file_name(_name(cell))

    def params_path(self, cell: Cell | str) -> Path:
        return self.cell_dir(cell) / PARAMS_FILE

    def curve_path(self, cell: Cell | str) -> Path:
        return self.cell_dir(cell) / CURVE_FILE

    def trajectories_path(self, cell: Cell | str) -> Path:
        """Episodes of the paper's trajectory figure (Zone LiDAR cells; `reproduce`)."""
        return self.cell_dir(cell) / TRAJECTORY_FILE

    def scratch_dir(self, cell: Cell | str) -> Path:
        """Where `reproduce` keeps the cell's resumable run directory."""
        return self.root / SCRATCH / grid.file_name(_name(cell))

    # --- reading -------------------------------------------------------------------------
    def read(self, cell: Cell | str) -> dict[str, Any] | None:
        path = self.cell_dir(cell) / CELL_FILE
        if not path.exists():
            return None
        return json.loads(path.read_text())

    def read_trajectories(self, cell: Cell | str) -> dict[str, Any] | None:
        path = self.trajectories_path(cell)
        return json.loads(path.read_text()) if path.exists() else None

    def names(self) -> list[str]:
        """Names of the cells the store holds, sorted."""
        if not self.root.exists():
            return []
        return sorted(grid.cell_name(p.parent.name) for p in self.root.glob(f"*/{CELL_FILE}"))

    def state(self, cell: Cell) -> str:
        """`done`, `partial` or `missing` against the grid entry `cell` (its suites and seeds)."""
        record = self.read(cell)
        if record is None:
            return "missing"
        return "done" if not missing_work(cell, record) else "partial"

    def trained_as(self, cell: Cell) -> Cell:
        """`cell` with the world and method options of its stored training: a cell trained
        before the grid changed one of them is loaded and evaluated as it was trained (`--rerun`
        trains it with the grid's). `cell` itself where nothing is trained yet."""
        record = self.read(cell)
        if not record or not record.get("training") or "config" not in record:
            return cell
        config = record["config"]
        return dataclasses.replace(
            cell, method_options=tuple(config.get("method_options", {}).items()),
            env_options=tuple(config.get("env_options", {}).items()))

    def load_params(self, cell: Cell | str) -> Any:
        """Seed 1's parameters with a leading seed axis of 1 (`experiment.load_params`), for the
        options the cell was trained with (`trained_as`)."""
        from specrl_jax.benchmark import experiment

        c = self.trained_as(grid.cell(cell) if isinstance(cell, str) else cell)
        return experiment.load_params(c.method, c.env_id, self.params_path(c), 1,
                                      env_options=dict(c.env_options) or None,
                                      method_options=c.options() or None)

    # --- writing -------------------------------------------------------------------------
    def write(self, cell: Cell | str, record: dict[str, Any]) -> Path:
        """Write `cell.json` (keys sorted, atomically), with its state recomputed when `cell`
        is a grid entry."""
        if isinstance(cell, Cell):
            record = dict(record, state="done" if not missing_work(cell, record) else "partial")
        path = self.cell_dir(cell) / CELL_FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(_clean(record), indent=1, sort_keys=True) + "\n")
        tmp.replace(path)
        return path

    def new_record(self, cell: Cell) -> dict[str, Any]:
        return {"schema": SCHEMA, "cell": cell.name, "config": cell.config(), "state": "partial",
                "suites": {}, "training": {}, "wall_s": {}, "versions": {}, "device": None}

    def add_suites(self, cell: Cell, results: Iterable[Any], wall_s: float | None = None) -> dict:
        """Merge evaluated suites (`SuiteResult`s) into the cell's record and write it: a suite
        scored alike on other seeds keeps them beside the new ones (`merge_seeds`)."""
        record = self.read(cell) or self.new_record(cell)
        for result in results:
            entry = suite_entry(result)
            entry["suite_version"] = specs.suite_version(result.suite)
            held = record["suites"].get(result.suite)
            record["suites"][result.suite] = (entry if held is None
                                              else merge_seeds(result.suite, held, entry))
        if wall_s is not None:
            record["wall_s"]["eval"] = record["wall_s"].get("eval", 0.0) + float(wall_s)
        self.write(cell, record)
        return record


def _name(cell: Cell | str) -> str:
    return cell.name if isinstance(cell, Cell) else cell


def missing_work(cell: Cell, record: dict[str, Any], part: Sequence[int] | None = None
                 ) -> list[str]:
    """What `record` lacks to complete grid entry `cell`: `train` when its training is not
    complete, and the suites not evaluated on all of its seeds or scored under an older version
    of the suite (`scored_now`). With `part` (seed numbers), what it lacks for those seeds:
    `train` when one of them is not trained (`trained_seeds`), and the suites not evaluated on
    every one of them."""
    todo = []
    training = record.get("training", {})
    if part is None:
        trained, wanted = training.get("complete", False), list(range(1, cell.seeds + 1))
    else:
        wanted = list(part)
        trained = set(wanted) <= set(trained_seeds(training))
    if cell.trains and not trained:
        todo.append("train")
    for suite in cell.suites:
        entry = record.get("suites", {}).get(suite)
        held = list(entry.get("seeds", [])) if entry is not None else []
        evaluated = held == wanted if part is None else set(wanted) <= set(held)
        if not evaluated or entry.get("episodes_per_seed") != cell.episodes \
                or not scored_now(suite, entry):
            todo.append(suite)
    return todo


def training_parts(training: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """A record's `training` by parts of the cell's seeds (`merge_training`): its `parts`, or
    a run of seeds 1 .. `num_seeds` at once as the one part of those seeds."""
    if "parts" in training:
        return dict(training["parts"])
    if "num_seeds" not in training:
        return {}
    seeds = list(training.get("seeds", range(1, training["num_seeds"] + 1)))
    return {_seed_label(seeds): {**training, "seeds": seeds}}


def trained_seeds(training: dict[str, Any]) -> list[int]:
    """The seeds a record's `training` has trained to the end (its complete parts')."""
    return sorted({seed for part in training_parts(training).values() if part.get("complete")
                   for seed in part["seeds"]})


def part_conflict(training: dict[str, Any], part: Sequence[int]) -> str | None:
    """Why seeds `part` cannot be trained beside a record's `training` (None: they can): a
    held part that shares some of its seeds but not all (`--seed-range` retrains a whole part,
    or new seeds)."""
    for label, held in training_parts(training).items():
        shared = set(held["seeds"]) & set(part)
        if shared and set(held["seeds"]) != set(part):
            return (f"seeds {_seed_label(part)} share seeds with the part {label} the store holds; "
                    f"train {label} again, or seeds outside it")
    return None


#: a part's settings that every part of a cell shares (else its seeds learned another way)
PART_SETTINGS = ("method", "env", "ppo", "env_steps_per_seed")
#: PPO settings added since some records were written, as those records were trained
LEGACY_PPO = {"entropy_per_action_dim": False}


def merge_training(training: dict[str, Any], summary: dict[str, Any], num_seeds: int
                   ) -> dict[str, Any]:
    """A record's `training` with a part's summary (`experiment.train` of some seeds, its
    `seeds`) added: `parts` holds each part's summary by its seeds (a held run of seeds 1 .. n
    becomes the part of those seeds; the part of the same seeds is replaced); beside them
    `seeds` (those trained to the end), `num_seeds`, `complete` (all `num_seeds` of the cell),
    `env_steps_per_s` (every part's steps over their summed time) and the settings the parts
    share (`PART_SETTINGS`, `physics`).

    Raises:
        ValueError: the part shares some seeds with a held part (`part_conflict`), or was
            trained with other settings (`PART_SETTINGS`) than the held complete parts (a
            stopped part's `env_steps_per_seed`, its progress, is not compared).
    """
    problem = part_conflict(training, summary["seeds"])
    if problem:
        raise ValueError(problem)
    parts = training_parts(training)
    label = _seed_label(summary["seeds"])
    # a stopped part's env_steps_per_seed counts the steps taken so far
    settings = [k for k in PART_SETTINGS
                if summary.get("complete", True) or k != "env_steps_per_seed"]
    for held_label, held in parts.items():
        differ = [k for k in settings if held_label != label and held.get("complete")
                  and k in held and k in summary
                  and _differs(_as_trained(k, held[k]), _as_trained(k, summary[k]))]
        if differ:
            raise ValueError(f"seeds {label} were trained with other {', '.join(differ)} than "
                             f"the held seeds {held_label}: train them alike (same device kind)")
    parts[label] = dict(summary)
    done = trained_seeds({"parts": parts})
    timed = [p for p in parts.values() if p.get("env_steps_per_s")]
    steps = [p.get("env_steps_per_seed", 0) * len(p["seeds"]) for p in timed]
    # the settings of a complete part, this one's first (it has every field the code writes
    # now), else the held ones' (a stopped part's env_steps_per_seed is progress)
    settled = summary if summary.get("complete", True) else next(
        (p for p in parts.values() if p.get("complete")), summary)
    merged = {k: settled[k] for k in (*PART_SETTINGS, "physics") if k in settled}
    merged.update(parts=parts, seeds=done, num_seeds=len(done),
                  complete=done == list(range(1, num_seeds + 1)),
                  env_steps_per_s=sum(steps) / sum(
                      s / p["env_steps_per_s"] for s, p in zip(steps, timed)) if timed else 0.0)
    return merged


def legacy_settings(cell: Cell, record: dict[str, Any]) -> dict[str, Any]:
    """The PPO settings (`LEGACY_PPO`) a cell trained before they existed ran with, where they
    differ from the current defaults: the entropy bonus summed over a Gaussian's action dimensions
    (LetterWorld's moves and GCRL-LTL's primitive choice are categorical)."""
    ppo = record.get("training", {}).get("ppo")
    if not ppo or cell.method == "gcrl" or families.family_of_id(cell.env_id).name == "letter":
        return {}
    return {k: v for k, v in LEGACY_PPO.items() if k not in ppo}


def _as_trained(setting: str, value: Any) -> Any:
    """A part's `setting` with the PPO settings its record predates filled in as it ran."""
    return {**LEGACY_PPO, **value} if setting == "ppo" and isinstance(value, dict) else value


def _differs(a: Any, b: Any) -> bool:
    """Settings that differ (dicts: on the keys both have, so fields added since compare)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return any(a[k] != b[k] for k in a.keys() & b.keys())
    return a != b


def _seed_label(seeds: Sequence[int]) -> str:
    return f"{min(seeds)}-{max(seeds)}"


def merge_seeds(suite: str, held: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """One suite entry from `held` and `new` (`suite_entry`s scored alike, on other seeds):
    per-seed rows in seed order, the summary over them all (`eval.metrics.summarize`). Where
    `held` is not scored as the suite is now (`scored_now`), was scored otherwise (specs,
    episodes, horizon, metrics) or shares seeds with `new`, `new` replaces it."""
    alike = ("method", "specs", "is_finite", "episodes_per_seed", "horizon")
    if (any(held.get(k) != new.get(k) for k in alike) or not scored_now(suite, held)
            or set(held["per_seed"]) != set(new["per_seed"])
            or set(held["seeds"]) & set(new["seeds"])):
        return new
    import numpy as np

    from specrl_jax.eval.metrics import summarize

    seeds = list(held["seeds"]) + list(new["seeds"])
    order = sorted(range(len(seeds)), key=seeds.__getitem__)
    per_seed = {m: [(held["per_seed"][m] + new["per_seed"][m])[i] for i in order]
                for m in new["per_seed"]}
    arrays = {m: np.array([[np.nan if x is None else x for x in row] for row in rows], float)
              for m, rows in per_seed.items()}
    summary = summarize(arrays, {suite: list(range(len(new["specs"])))})
    return _clean({**new, "seeds": sorted(seeds), "per_seed": per_seed, "summary": summary})


def merge_curves(parts: Sequence[tuple[Sequence[int], list[dict[str, Any]]]]
                 ) -> list[dict[str, Any]]:
    """Training curves of parts of a cell's seeds (`(seeds, rows)`, a row per update of seed
    means, `metrics.jsonl`) as one over all their seeds: per update (those every part has),
    scalars averaged with each part's seed count as weight, per-seed lists joined in seed order,
    `wall_s` summed (the parts trained one after the other)."""
    parts = sorted(parts, key=lambda p: min(p[0]))
    weights = [len(seeds) for seeds, _ in parts]
    by_update = [{row["update"]: row for row in rows} for _, rows in parts]
    updates = sorted(set.intersection(*(set(u) for u in by_update)))
    merged = []
    for update in updates:
        rows = [u[update] for u in by_update]
        out = {}
        for key in rows[0]:
            values = [r.get(key) for r in rows]
            if key in ("update", "env_steps"):
                out[key] = values[0]
            elif key == "wall_s":
                out[key] = sum(values)
            elif all(isinstance(v, list) for v in values):
                out[key] = [x for v in values for x in v]
            elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
                out[key] = sum(w * v for w, v in zip(weights, values)) / sum(weights)
        merged.append(out)
    return merged


def suite_seeds(record: dict[str, Any]) -> int:
    """The fewest seeds any evaluated suite of a record has (0 if none)."""
    counts = [len(e.get("seeds", [])) for e in record.get("suites", {}).values()]
    return min(counts) if counts else 0


def seed_means(entry: dict[str, Any], metric: str) -> list[float]:
    """Each seed's `metric` over the suite's specs (the record's `per_seed`, seeds x specs), in
    seed order."""
    return [sum(row) / len(row) for row in entry["per_seed"][metric]]


def suite_metric(entry: dict[str, Any], metric: str) -> tuple[float | None, float | None]:
    """(mean, std) over seeds of a suite's `metric` (the record's summary; None if not there)."""
    group = next(iter(entry["summary"]["groups"].values()), {})
    return group.get(f"{metric}_mean"), group.get(f"{metric}_std")


def default() -> Store:
    return Store()


def params_path(cell: Cell | str, root: str | os.PathLike | None = None) -> Path:
    """Path of a cell's seed-1 parameters in the store (default: the package's)."""
    return Store(root).params_path(cell)


def states(cells: Sequence[Cell], store: Store | None = None) -> dict[str, str]:
    store = store or Store()
    return {c.name: store.state(c) for c in cells}
