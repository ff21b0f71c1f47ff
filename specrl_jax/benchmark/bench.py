"""Score any policy on the whole benchmark: every paper suite of the selected worlds, beside the
five baselines' numbers (`specrl-jax bench`).

    from specrl_jax.benchmark import bench
    report = bench.score(my_agent, worlds=("letter",), seeds=5, episodes=100, out="bench/")

`score` runs each world's suites with one compiled evaluator (`eval.suites.evaluate_suites`) or,
with `backend="gymnasium"`, a numpy callable through the Gymnasium vector env (`legacy`). The
report directory holds:

- `results.json`: the settings, the backend, the versions of the package and of every suite
  (`specs.suite_version`), per world a summary, per suite the metrics per spec and seed and their
  mean and std over seeds, and the baselines' numbers with where they come from;
- `metrics.csv`: one row per (suite, spec, seed) with every metric;
- `tables.md`: the paper's tables, the policy's row beside the baselines' reproduction (the
  results store, `benchmark.store`) and the paper's published numbers (`benchmark.paper`);
- `bench.png`: success rate of each finite suite and accepting visits of each infinite one.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from specrl_jax import families, specs
from specrl_jax.benchmark import agent as agents
from specrl_jax.eval.metrics import METRICS

#: the benchmark's worlds and the env IDs that hold their paper suites (the arm's two suite
#: families need a grippers-only and a grippers-and-arm world)
WORLDS: dict[str, tuple[str, tuple[str, ...]]] = {
    "letter": (families.LETTER.name, ("LetterLTL0-v0",)),
    "zone": (families.ZONE.name, ("PointLTL0-v0",)),
    "arm": (families.ARM.name, ("PandaLTLReach0Joints-v0", "PandaLTLReach1Joints-v0")),
    "multi_agent": (families.MULTI_AGENT_ZONE.name, ("PointLTL0MA2-v0",)),
}
BACKENDS = ("jax", "gymnasium")
DEFAULT_SEEDS = 5
DEFAULT_EPISODES = 100
FINITE_COLUMNS = ("eta_s", "eta_v", "mu")
INFINITE_COLUMNS = ("mu_acc", "eta_v")


@dataclasses.dataclass(frozen=True)
class WorldScore:
    """One world's suites (`SuiteResult`s over its env IDs), or why it was skipped."""

    world: str
    results: tuple[Any, ...]
    wall_s: float
    skipped: str = ""

    def summary(self) -> dict[str, float]:
        """Mean `eta_s` over the finite suites, `eta_v` over all, `mu_acc` over the infinite."""
        finite = [r.suite_metrics() for r in self.results if r.is_finite]
        infinite = [r.suite_metrics() for r in self.results if not r.is_finite]
        return {"eta_s": _mean(m["eta_s_mean"] for m in finite),
                "eta_v": _mean(m["eta_v_mean"] for m in finite + infinite),
                "mu_acc": _mean(m["mu_acc_mean"] for m in infinite)}

    def line(self) -> str:
        if self.skipped:
            return f"{self.world}: skipped ({self.skipped})"
        s = self.summary()
        return (f"{self.world}: eta_s {_text(s['eta_s'])}, eta_v {_text(s['eta_v'])}, "
                f"mu_acc {_text(s['mu_acc'], 1)} over {len(self.results)} suites "
                f"({self.wall_s:.0f}s)")


@dataclasses.dataclass(frozen=True)
class BenchReport:
    """What `score` measured; `out` is the report directory when one was written."""

    name: str
    backend: str
    worlds: tuple[WorldScore, ...]
    config: dict[str, Any]
    out: Path | None = None

    def lines(self) -> list[str]:
        return [w.line() for w in self.worlds]


def _mean(values: Any) -> float:
    kept = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.mean(kept)) if kept else math.nan


def _text(value: float | None, digits: int = 2) -> str:
    return "-" if value is None or math.isnan(value) else f"{value:.{digits}f}"


def world_envs(world: str) -> tuple[str, list[tuple[str, tuple[str, ...]]]]:
    """`(family, [(env ID, its paper suites)])` of a benchmark world (`WORLDS`), a family name
    or an env ID."""
    from specrl_jax.benchmark.experiment import suites_for

    if world in WORLDS:
        family, env_ids = WORLDS[world]
    elif world in families.list_families():
        family, env_ids = world, (families.get(world).reference_env,)
    else:
        family, env_ids = families.family_of_id(world).name, (world,)
    pairs = [(env_id, suites_for(env_id)) for env_id in env_ids]
    return family, pairs


def default_worlds(policy: Any) -> tuple[str, ...]:
    """The worlds a policy is scored on by default: a trained run's (or store cell's) own world,
    the families an `Agent` declares, else every benchmark world."""
    if isinstance(policy, str):
        from specrl_jax.benchmark import grid

        config = Path(policy) / "config.json"
        if config.exists():
            return (json.loads(config.read_text())["env"],)
        if policy in grid.BY_NAME:
            return (grid.cell(policy).env_id,)
    if isinstance(policy, agents.Agent) and policy.worlds is not None:
        return tuple(w for w, (family, _) in WORLDS.items() if family in policy.worlds)
    return tuple(WORLDS)


def check_worlds(worlds: Sequence[str]) -> tuple[str, ...]:
    """Known world names, family names or env IDs; a clear error otherwise."""
    from specrl_jax.envs.registry import list_envs

    known = set(WORLDS) | set(families.list_families()) | set(list_envs())
    unknown = [w for w in worlds if w not in known]
    if unknown:
        raise ValueError(f"unknown world {', '.join(map(repr, unknown))}; accepted: "
                         f"{', '.join(WORLDS)}, a family ({', '.join(families.list_families())}) "
                         "or an env ID (`specrl-jax envs`)")
    return tuple(worlds)


def score(policy: Any, worlds: Sequence[str] | None = None, suites: Sequence[str] | None = None,
          seeds: int | Sequence[int] = DEFAULT_SEEDS, episodes: int = DEFAULT_EPISODES, *,
          backend: str = "jax", horizon: int | None = None, out: str | Path | None = None,
          name: str | None = None, num_envs: int | None = None,
          log: Callable[[str], None] = print) -> BenchReport:
    """Score `policy` on every paper suite of `worlds`; write a report directory to `out`.

    Args:
        policy: an `agent.Agent`, a policy function or `StatefulPolicy`, a reference string
            (`agent.load`: a run directory, a store cell, `module:factory`, random, oracle), or
            with `backend="gymnasium"` a numpy callable `(obs, legacy.LegacyTask) -> actions`.
        worlds: names of `WORLDS`, family names or env IDs (default `default_worlds(policy)`).
        suites: only these suites (default: every paper suite of each world).
        seeds: a count n (seeds 1..n) or the seeds; ignored by a trained run (its own seeds).
        episodes: per seed and spec.
        backend: "jax" (one compiled evaluator per world) or "gymnasium" (`legacy.evaluate`).
        horizon: overrides every suite's episode length (smoke runs).
        out: the report directory (None: no files).
        name: the policy's label in the tables.
        num_envs: gymnasium backend: episodes stepped side by side.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; accepted: {', '.join(BACKENDS)}")
    worlds = check_worlds(default_worlds(policy) if worlds is None else tuple(worlds))
    seed_list = tuple(range(1, seeds + 1)) if isinstance(seeds, int) else tuple(seeds)
    if not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive int, got {episodes!r}")
    scores = []
    for world in worlds:
        _family, pairs = world_envs(world)
        start, results, skipped = time.perf_counter(), [], ""
        for env_id, env_suites in pairs:
            chosen = [s for s in env_suites if suites is None or s in suites]
            if not chosen:
                continue
            log(f"{world}: {env_id}, {len(chosen)} suites, {len(seed_list)} seeds x {episodes} "
                f"episodes ({backend} backend)")
            try:
                results += _evaluate(policy, env_id, chosen, episodes, seed_list, backend,
                                     horizon, num_envs, name, log)
            except _Unsupported as err:
                skipped = str(err)
                log(f"{world}: skipped: {skipped}")
                break
        if suites is not None and not results and not skipped:
            skipped = "none of the given suites belongs to it"
        scores.append(WorldScore(world, tuple(results), time.perf_counter() - start, skipped))
        log(scores[-1].line())
    # the name given, else the one the policy declares (its results' label), else its reference
    label = name or next((r.method for w in scores for r in w.results), None) or _label(policy)
    config = {"policy": policy if isinstance(policy, str) else label, "worlds": list(worlds),
              "suites": None if suites is None else list(suites), "seeds": list(seed_list),
              "episodes": episodes, "backend": backend, "horizon": horizon}
    report = BenchReport(label, backend, tuple(scores), config)
    if out is not None:
        report = dataclasses.replace(report, out=write_report(report, out))
    return report


class _Unsupported(ValueError):
    """The policy does not act in this world (it says so)."""


def _label(policy: Any) -> str:
    if isinstance(policy, agents.Agent):
        return policy.name
    if isinstance(policy, str):
        return Path(policy).name if Path(policy).exists() else policy.rsplit(":", 1)[-1]
    return getattr(policy, "__name__", "policy")


def _evaluate(policy: Any, env_id: str, suites: Sequence[str], episodes: int,
              seeds: tuple[int, ...], backend: str, horizon: int | None, num_envs: int | None,
              name: str | None, log: Callable[[str], None]) -> list:
    """One env's suites; labelled `name`, else the agent's own name."""
    if backend == "gymnasium":
        from specrl_jax.benchmark import legacy

        if families.family_of_id(env_id).name == families.MULTI_AGENT_ZONE.name:
            raise _Unsupported("the gymnasium backend scores single-agent worlds")
        if isinstance(policy, str):  # module:factory, its factory(world) a numpy callable
            from specrl_jax.envs.registry import make

            policy = agents.load_factory(policy)(make(env_id)[0])
        if not callable(policy) or isinstance(policy, agents.Agent):
            raise TypeError("the gymnasium backend takes a numpy callable (obs, task) -> actions")
        return legacy.evaluate(policy, env_id, suites, episodes, seeds, horizon, num_envs,
                               name or _label(policy), log)
    if isinstance(policy, str):
        loaded = agents.load(policy, env_id)
        if isinstance(loaded, agents.TrainedRun) and len(loaded.seeds) == 1:
            loaded = agents.with_seed_count(loaded, len(seeds))  # a store cell's seed 1
    else:
        loaded = agents.as_agent(policy)
    if isinstance(loaded, agents.Agent):
        family = families.family_of_id(env_id).name
        if not loaded.supports(family):
            raise _Unsupported(f"policy {loaded.name!r} declares no support for {family} worlds")
    label = name or loaded.name
    results = agents.evaluate(loaded, env_id, suites, episodes, seeds, horizon, log)
    return [dataclasses.replace(r, method=label) for r in results]


# ---------------------------------------------------------------------------------------------
# The report directory


def versions(report: BenchReport) -> dict[str, Any]:
    """The package's versions and every evaluated suite's version."""
    from specrl_jax.eval.report import versions as package_versions

    suites = sorted({r.suite for w in report.worlds for r in w.results})
    return {**package_versions(), "suites": {s: specs.suite_version(s) for s in suites}}


def baselines(env_id: str, suite: str, metrics: Sequence[str]) -> list[dict[str, Any]]:
    """The five baselines' numbers for one suite of one world: the results store's
    reproduction (mean and std over its seeds) and the paper's, each naming its source."""
    from specrl_jax.benchmark import grid, paper
    from specrl_jax.benchmark.report import method_label
    from specrl_jax.benchmark.store import Store, suite_metric

    rows, store = [], Store()
    for cell in grid.GRID:
        if cell.env_id != env_id or suite not in cell.suites:
            continue
        record = store.read(cell)
        entry = (record or {}).get("suites", {}).get(suite)
        if entry is not None:
            values = {m: suite_metric(entry, m) for m in metrics}
            rows.append({"method": method_label(cell), "kind": "store", "values": values,
                         "source": f"results store {cell.name} ({len(entry.get('seeds', []))} "
                                   f"seeds x {entry.get('episodes_per_seed')} episodes)"})
        numbers = {m: paper.lookup(env_id, suite, cell.method, m) for m in metrics}
        if any(numbers.values()) and not cell.variant:
            rows.append({"method": method_label(cell), "kind": "paper",
                         "values": {m: (n.mean, n.std) if n else (None, None)
                                    for m, n in numbers.items()},
                         "source": "paper: " + "; ".join(sorted({n.source for n in numbers.values()
                                                                 if n}))})
    return rows


def write_report(report: BenchReport, out: str | Path) -> Path:
    """`results.json`, `metrics.csv`, `tables.md` and `bench.png` under `out`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    suite_versions = versions(report)
    entries, rows = [], []
    for world in report.worlds:
        for item in world.results:
            r = item.result
            per_seed = r.per_seed()
            version = suite_versions["suites"][item.suite]
            metrics = FINITE_COLUMNS if item.is_finite else INFINITE_COLUMNS
            entries.append({
                "world": world.world, "env": item.env_id, "suite": item.suite,
                "suite_version": version, "specs": list(r.spec_names), "seeds": list(r.seeds),
                "episodes_per_seed": r.episodes_per_seed, "horizon": r.horizon,
                "summary": item.summary(), "per_seed": {m: v.tolist() for m, v in per_seed.items()},
                "baselines": baselines(item.env_id, item.suite, metrics)})
            for k, formula in enumerate(r.spec_names):
                for s, seed in enumerate(r.seeds):
                    rows.append([world.world, item.env_id, item.suite, version, k, formula, seed]
                                + [float(per_seed[m][s, k]) for m in METRICS])
    document = {"name": report.name, "backend": report.backend, "config": report.config,
                "versions": suite_versions,
                "summary": {w.world: {"skipped": w.skipped} if w.skipped else
                            {**w.summary(), "wall_s": w.wall_s} for w in report.worlds},
                "results": entries}
    (out / "results.json").write_text(json.dumps(_json_safe(document), indent=1))
    with (out / "metrics.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["world", "env", "suite", "suite_version", "spec", "formula", "seed",
                         *METRICS])
        writer.writerows(rows)
    (out / "tables.md").write_text(tables(report, entries, suite_versions))
    plot(report, entries, out / "bench.png")
    return out


def _json_safe(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _cell(mean: float | None, std: float | None, metric: str) -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "-"
    digits = 1 if metric in ("mu", "mu_acc") else 2
    return f"{mean:.{digits}f}" + ("" if std is None or math.isnan(std) else f" ± {std:.{digits}f}")


def tables(report: BenchReport, entries: Sequence[dict[str, Any]],
           suite_versions: dict[str, Any]) -> str:
    """The paper's layout per env and horizon kind: one row per policy (this one, then the
    baselines' reproduction and published numbers), columns suite x metric."""
    v = suite_versions
    lines = [f"# Benchmark: {report.name}", "",
             (f"Backend {report.backend}; seeds {report.config['seeds']}, "
             f"{report.config['episodes']} episodes per seed and spec; specrl_jax "
             f"{v['specrl_jax']}, jax {v['jax']}, device {v['device']}."), "",
             "Suite versions: " + ", ".join(f"`{s}` {h}" for s, h in v["suites"].items()) + ".",
             "", "## Summary", ""]
    lines += [f"- {line}" for line in report.lines()]
    for env_id in dict.fromkeys(e["env"] for e in entries):
        for finite, columns in ((True, FINITE_COLUMNS), (False, INFINITE_COLUMNS)):
            chosen = [e for e in entries if e["env"] == env_id and _is_finite(e) == finite]
            if chosen:
                lines += ["", f"## {env_id}, {'finite' if finite else 'infinite'}-horizon suites",
                          ""] + _table(report.name, chosen, columns)
    return "\n".join(lines) + "\n"


def _is_finite(entry: dict[str, Any]) -> bool:
    return specs.suite_info(entry["suite"]).is_finite


def _table(name: str, chosen: Sequence[dict[str, Any]], columns: Sequence[str]) -> list[str]:
    header = ["policy"] + [f"{e['suite'].split('/', 1)[1]} {c}" for e in chosen for c in columns]
    lines = ["| " + " | ".join(header + ["source"]) + " |", "|" + "---|" * (len(header) + 1)]
    own = [name]
    for e in chosen:
        group = next(iter(e["summary"]["groups"].values()))
        own += [_cell(group.get(f"{c}_mean"), group.get(f"{c}_std"), c) for c in columns]
    lines.append("| " + " | ".join(own + ["this run"]) + " |")
    keys = list(dict.fromkeys((b["method"], b["kind"]) for e in chosen for b in e["baselines"]))
    sources: dict[tuple[str, str], list[str]] = {}
    for method, kind in keys:
        row = [f"{method} ({'reproduction' if kind == 'store' else 'paper'})"]
        for e in chosen:
            found = next((b for b in e["baselines"] if (b["method"], b["kind"]) == (method, kind)),
                         None)
            if found:
                sources.setdefault((method, kind), []).append(found["source"])
            row += [_cell(*(found["values"].get(c, (None, None)) if found else (None, None)), c)
                    for c in columns]
        lines.append("| " + " | ".join(row + ["; ".join(dict.fromkeys(
            sources.get((method, kind), [])))]) + " |")
    return lines


def plot(report: BenchReport, entries: Sequence[dict[str, Any]], path: Path) -> Path:
    """Per env: the finite suites' success rate and the infinite suites' accepting visits,
    this policy beside the baselines' reproduction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env_ids = list(dict.fromkeys(e["env"] for e in entries)) or ["(nothing scored)"]
    fig, axes = plt.subplots(len(env_ids), 2, figsize=(11, 3.2 * len(env_ids)), squeeze=False)
    for row, env_id in enumerate(env_ids):
        for col, (finite, metric) in enumerate(((True, "eta_s"), (False, "mu_acc"))):
            ax = axes[row, col]
            chosen = [e for e in entries if e["env"] == env_id and _is_finite(e) == finite]
            labels = [e["suite"].split("/", 1)[1] for e in chosen]
            series = {report.name: [next(iter(e["summary"]["groups"].values())).get(
                f"{metric}_mean") for e in chosen]}
            for e_i, e in enumerate(chosen):
                for b in e["baselines"]:
                    if b["kind"] == "store":
                        series.setdefault(b["method"], [None] * len(chosen))[e_i] = \
                            b["values"][metric][0]
            width = 0.8 / max(len(series), 1)
            for i, (label, values) in enumerate(series.items()):
                heights = [np.nan if v is None else v for v in values]
                ax.bar(np.arange(len(chosen)) + i * width, heights, width, label=label)
            ax.set_xticks(np.arange(len(chosen)) + 0.4 - width / 2, labels, fontsize=8)
            ax.set_title(f"{env_id}: {'success rate eta_s' if finite else 'accepting visits mu_acc'}",
                         fontsize=9)
            if finite:
                ax.set_ylim(0, 1.05)
            if chosen:
                ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
