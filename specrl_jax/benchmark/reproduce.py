"""Reproduce the paper's experiment grid into the results store: `specrl-jax reproduce`.

For each selected cell (`grid.select`): skip it when the store holds it complete; otherwise
train its seeds side by side (`experiment.train` into `<store>/scratch/<cell>/run`, resumed
from its checkpoint after an interruption), write seed 1's parameters and the training curve,
then evaluate every suite not yet evaluated on all seeds (finite suites in one call, infinite
ones in another; `cell.json` is written after each, so an interrupted evaluation resumes
there). An evaluation-only cell (the multi-agent coordinator) runs the seed-1 parameters of its
`params_from` cell on every seed. `rerun` discards a cell's stored results first.

On a lent machine, `--store $OUT/store` keeps the results (and the resumable run directories
under its `scratch/`) where they come back; copy the cell directories into the package store.

On a host with several GPUs the cells run side by side, one per GPU (a subprocess each with
`CUDA_VISIBLE_DEVICES`); on one GPU or a CPU, one after the other in this process.
`cells_per_gpu` K > 1 runs K such subprocesses on each GPU, each with 1/K of the memory that one
process would take: cells whose steps are too small to fill a GPU (the MuJoCo worlds at the
grid's batches wait on kernel launches) share it. In a job of
several processes (`baselines.hosts.join`: `specrl-jax reproduce --coordinator ...`) the cells
run one after the other, each trained over every process's devices; every process evaluates
(the same episodes on its own devices), process 0 alone writes the store.

    from specrl_jax.benchmark import reproduce
    reproduce.reproduce("LetterLTL0-v0/genz")
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np

from specrl_jax import families
from specrl_jax.baselines import hosts
from specrl_jax.benchmark import estimate, grid
from specrl_jax.benchmark.grid import Cell
from specrl_jax.benchmark.store import (
    LEGACY_PPO,
    Store,
    legacy_settings,
    merge_curves,
    merge_training,
    missing_work,
    part_conflict,
    suite_seeds,
    trained_seeds,
)

Log = Callable[[str], None]


# ---------------------------------------------------------------------------------------------
# One cell


def default_train(cell: Cell, run_dir: Path, log: Log, max_wall_s: float | None = None,
                  on_compiled: Callable[[], None] | None = None,
                  seeds: Sequence[int] | None = None) -> tuple[Any, dict[str, Any]]:
    """Train `cell`'s seeds (or `seeds`, consecutive, of them) side by side with the family's
    shape on this device (`experiment.default_overrides`, with the method's accelerator
    settings) and the cell's PPO overrides; the worlds reset from a bank of exactly sampled
    layouts, of the size
    `WorldFamily.map_bank_size` gives on this device. `max_wall_s` stops training at the first
    checkpoint after that many seconds (resumable); `on_compiled()` runs once the training step
    has compiled (`experiment.train`)."""
    import jax

    from specrl_jax.benchmark import experiment

    platform = jax.devices()[0].platform
    world_family = experiment.family(cell.env_id)
    images = experiment.observes_images(cell.env_id, dict(cell.env_options))
    overrides = experiment.default_overrides(platform, cell.total_steps, world_family, cell.method, images)
    overrides.update(dict(cell.ppo))
    map_bank = families.get(world_family).map_bank_size(platform)
    seeds = list(seeds) if seeds is not None else list(range(1, cell.seeds + 1))
    return experiment.train(cell.method, cell.env_id, run_dir, overrides, len(seeds), log=log,
                            max_wall_s=max_wall_s, map_bank=map_bank,
                            env_options=dict(cell.env_options) or None,
                            method_options=cell.options() or None, on_compiled=on_compiled,
                            first_seed=seeds[0])


def default_load(cell: Cell, path: Path, num_seeds: int) -> Any:
    from specrl_jax.benchmark import experiment

    return experiment.load_params(cell.method, cell.env_id, path, num_seeds,
                                  env_options=dict(cell.env_options) or None,
                                  method_options=cell.options() or None)


def default_evaluate(cell: Cell, params: Any, suites: Sequence[str], log: Log,
                     seeds: Sequence[int] | None = None) -> list:
    """`SuiteResult`s of `suites` for seeds 1..cell.seeds, or `seeds` (`params` with a seed
    axis, one entry per seed)."""
    from specrl_jax.benchmark import experiment

    if not cell.trains:
        return evaluate_coordinator(cell, params, suites, log)
    return experiment.evaluate(cell.method, cell.env_id, params, suites, cell.episodes, log=log,
                               env_options=dict(cell.env_options) or None,
                               method_options=cell.options() or None, seeds=seeds)


def default_prepare(cell: Cell, suites: Sequence[str], log: Log,
                    seeds: Sequence[int] | None = None) -> Future | None:
    """`default_evaluate`'s program for `cell`'s trained parameters (of `seeds`, default all),
    compiling in a background thread (before they exist, beside training) where that is safe:
    a trained cell on an accelerator, a job of one process, a world lowered without MuJoCo Warp
    (`experiment.lowers_in_threads`); else None. The future holds `evaluate(params)`."""
    import jax

    from specrl_jax.benchmark import experiment
    from specrl_jax.envs.registry import make

    env_options, method_options = dict(cell.env_options) or None, cell.options() or None
    if (not cell.trains or jax.process_count() > 1 or jax.devices()[0].platform == "cpu"
            or not experiment.lowers_in_threads(make(cell.env_id, **(env_options or {}))[0])):
        return None
    return experiment.prepare_evaluation_in_background(
        cell.method, cell.env_id, cell.seeds, suites, cell.episodes, log, env_options,
        method_options, seeds)


def _save_seed1(params: Any, path: Path) -> None:
    import jax
    from flax import serialization

    path.parent.mkdir(parents=True, exist_ok=True)
    one = jax.tree.map(lambda x: x[0], jax.device_get(params))
    path.write_bytes(serialization.to_bytes(one))


def _versions() -> tuple[dict[str, str], str]:
    from specrl_jax.eval.report import versions

    v = versions()
    return v, v.pop("device")


def run_cell(cell: Cell, store: Store | None = None, log: Log = print,
             train: Callable | None = None, evaluate: Callable | None = None,
             load: Callable | None = None, trajectories: Callable | bool = True,
             deadline: float | None = None, prepare: Callable | None = None,
             part: Sequence[int] | None = None) -> dict[str, Any]:
    """Complete `cell` in `store`: train if its training is not complete, evaluate the suites
    it lacks, record the trajectory figure's episodes on a Zone LiDAR world; returns its
    record. `part` (consecutive seed numbers, e.g. `range(3, 6)`) does that for those seeds
    only, beside the seeds the store holds (`store.merge_training`, `merge_seeds`,
    `merge_curves`), so a cell too long for one machine's time is completed in parts; they get
    the keys they have in one training of every seed (`runs.seed_keys`).
    `train(cell, run_dir, log, max_wall_s, seeds=) -> (params, summary)`, `evaluate(cell,
    params, suites, log, seeds=) -> [SuiteResult]`, `load(cell, path, num_seeds)` and
    `trajectories(cell, params) -> dict` replace the defaults (tests; `trajectories=False`: none
    recorded); `prepare(cell, suites, log, seeds) -> Future | None` starts compiling the
    evaluation of every suite once the training step has compiled (`train` is then also given
    `on_compiled=`), its future holding `evaluate(params)` (default with the default training
    and evaluation: `default_prepare`). Past `deadline` (a `time.monotonic()` value) training
    stops at its next checkpoint, and an evaluation estimated to end past it
    (`estimate.evaluation_seconds`) does not start; the cell stays partial, to resume. In a job
    of several processes every process calls it alike and process 0 writes."""
    store = store or Store()
    problem = part_problem(cell, store, part)
    if problem:
        raise ValueError(problem)
    part = None if part is None or list(part) == list(range(1, cell.seeds + 1)) else list(part)
    whole = part is None
    seeds = list(range(1, cell.seeds + 1)) if whole else part
    prepare = prepare or (default_prepare if train is None and evaluate is None else None)
    train, evaluate = train or default_train, evaluate or default_evaluate
    load = load or default_load
    writer = hosts.is_writer()
    figure = bool(trajectories) and records_trajectories(cell)
    record = store.read(cell) or store.new_record(cell)
    run_dir = store.scratch_dir(cell) / ("run" if whole else f"run_seeds{seeds[0]}-{seeds[-1]}")
    # stored parameters, a training to resume, or the other parts of a cell's seeds keep the
    # options they were trained with; a training from nothing takes the grid's
    if cell.trains and (run_dir.exists() or store.params_path(cell).exists() or not whole):
        cell = store.trained_as(cell)
    record["config"] = cell.config()
    todo = missing_work(cell, record, part)
    # the figure's episodes belong to the stored seed-1 parameters: drawn when missing
    draw = (figure and 1 in seeds and not store.trajectories_path(cell).exists()
            and store.params_path(cell).exists())
    if not todo and not draw:
        log(f"{cell.name}: done, skipped")
        return record
    trained = run_dir / "params.msgpack"
    params = None
    prepared: list[Future | None] = []  # the evaluation of every suite, compiled while training
    if cell.trains:
        suites_todo = [s for s in todo if s != "train"]
        if "train" in todo or not trained.exists() and suites_todo:
            # (re)train: suites evaluated on other parameters (fewer seeds) are stale
            which = "" if whole else f" (seeds {seeds[0]}-{seeds[-1]} of {cell.seeds})"
            log(f"{cell.name}: training {len(seeds)} x {cell.total_steps:,} steps{which} in "
                f"{run_dir}")
            start = time.perf_counter()

            def compile_evaluator() -> None:  # on the host while the device trains
                try:
                    prepared.append(prepare(cell, list(cell.suites), log, seeds))
                except Exception as err:  # noqa: BLE001 (compiled after training instead)
                    log(f"{cell.name}: the evaluator will compile after training "
                        f"({type(err).__name__}: {err})")
            params, summary = train(cell, run_dir, log, _seconds_left(deadline), seeds=seeds,
                                    **({"on_compiled": compile_evaluator} if prepare else {}))
            summary = {**_plain(summary), "complete": bool(summary.get("complete", True)),
                       "seeds": seeds}
            wall = training_wall(summary, time.perf_counter() - start)
            held = record.get("training", {})
            if whole:
                record.update(training=summary, wall_s={"train": wall}, suites={})
            else:  # the held seeds' training and scores stay; those of these seeds are redone
                curve_seeds = [s for s in trained_seeds(held) if s not in seeds]
                record["training"] = merge_training(held, summary, cell.seeds)
                record["wall_s"] = {**record.get("wall_s", {}), "train": sum(
                    training_wall(p, wall) for p in record["training"]["parts"].values())}
                record["suites"] = {k: e for k, e in record.get("suites", {}).items()
                                    if not set(e.get("seeds", [])) & set(seeds)}
            record["versions"], record["device"] = _versions()
            record.pop("source", None)
            record.pop("params_note", None)
            draw = figure and 1 in seeds  # new seed-1 parameters: the figure is drawn again
            if writer:
                if 1 in seeds:
                    store.trajectories_path(cell).unlink(missing_ok=True)
                    if summary["complete"]:
                        _save_seed1(params, store.params_path(cell))
                    else:  # not the trained parameters (a stopped GCRL-LTL's: its policy alone)
                        store.params_path(cell).unlink(missing_ok=True)
                if whole or summary["complete"]:  # a part's curve joins the others once whole
                    _store_curve(store, cell, run_dir, None if whole else curve_seeds, seeds)
                store.write(cell, record)
            if not summary["complete"]:
                log(f"{cell.name}: training stopped before its last update; rerun to resume")
                hosts.barrier(f"{cell.name} written")
                return record
        elif suites_todo:
            params = load(cell, trained, len(seeds))
        elif draw:
            params = load(cell, store.params_path(cell), 1)
    else:
        source = grid.cell(cell.params_from) if cell.params_from in grid.BY_NAME else None
        # the source cell's parameters in this store, else in the package's
        held = [s for s in (store, Store()) if source and s.params_path(source).exists()]
        if not held:
            raise ValueError(f"{cell.name} runs the seed-1 parameters of {cell.params_from}, "
                             "which the store does not hold "
                             f"({store.params_path(cell.params_from)})")
        params = load(held[0].trained_as(source), held[0].params_path(source), 1)
        record["training"] = {"params_from": cell.params_from}
    missing = [s for s in missing_work(cell, record, part) if s != "train"]
    # one call for every missing suite: one compiled evaluator serves the finite and infinite
    # horizons (`eval.suites.evaluate_suites`), compiled once per cell instead of per horizon
    if missing:
        # an evaluation that would outrun the time left is not started (a time slot's end
        # would kill it and lose it)
        needs = estimate.evaluation_seconds(cell) * len(missing) / len(cell.suites)
        if _out_of_time(deadline if deadline is None else deadline - needs):
            log(f"{cell.name}: time limit reached before evaluating {', '.join(missing)} (about "
                f"{_duration(needs)}, {_duration(_seconds_left(deadline))} left); rerun to "
                "resume")
            hosts.barrier(f"{cell.name} written")
            return record
        log(f"{cell.name}: evaluating {', '.join(missing)} ({len(seeds)} seeds x "
            f"{cell.episodes} episodes)")
        start = time.perf_counter()
        evaluator = None
        if prepared and prepared[0] is not None and missing == list(cell.suites):
            try:
                evaluator = prepared[0].result()
            except Exception as err:  # noqa: BLE001 (compiled the usual way instead)
                log(f"{cell.name}: compiling the evaluator beside training failed "
                    f"({type(err).__name__}: {err}); compiling it again")
        results = (evaluator(params) if evaluator is not None
                   else evaluate(cell, params, missing, log, seeds=seeds))
        if writer:
            record["versions"], record["device"] = _versions()
            store.write(cell, record)
            record = store.add_suites(cell, results, time.perf_counter() - start)
    if draw and params is not None:
        log(f"{cell.name}: recording the trajectory figure's episodes")
        recorder = record_trajectories if trajectories is True else trajectories
        try:  # a figure's episodes: a failure here leaves the cell's results as they are
            episodes = recorder(cell, params)
        except Exception as err:  # noqa: BLE001
            log(f"{cell.name}: no trajectories recorded: {type(err).__name__}: {err}")
        else:
            if writer:
                store.trajectories_path(cell).write_text(json.dumps(episodes, sort_keys=True)
                                                         + "\n")
    hosts.barrier(f"{cell.name} written")  # the next reads see what process 0 wrote
    result = store.read(cell)
    log(f"{cell.name}: {result['state']}")
    return result


def part_problem(cell: Cell, store: Store, part: Sequence[int] | None) -> str | None:
    """Why seeds `part` of `cell` cannot be trained and evaluated beside what `store` holds
    (None: they can, or `part` is None): a cell that trains nothing, seeds that are not
    consecutive seeds of the cell, or that share some seeds with a held part
    (`store.part_conflict`)."""
    if part is None:
        return None
    part = list(part)
    if not cell.trains or not part or part != list(range(part[0], part[-1] + 1)) \
            or part[0] < 1 or part[-1] > cell.seeds:
        return (f"{cell.name}: seeds {part} are not a part of its training (seeds "
                f"1-{cell.seeds}, consecutive, e.g. 3-{cell.seeds})")
    conflict = part_conflict((store.read(cell) or {}).get("training", {}), part)
    return f"{cell.name}: {conflict}" if conflict else None


def _store_curve(store: Store, cell: Cell, run_dir: Path, held_seeds: list[int] | None,
                 seeds: list[int]) -> None:
    """The store's training curve after training `seeds` in `run_dir`: that run's
    (`held_seeds` None: every seed), or, for a part, merged with the held curve of
    `held_seeds` (`merge_curves`)."""
    from specrl_jax.baselines.runs import read_metrics

    if not (run_dir / "metrics.jsonl").exists():
        return
    path = store.curve_path(cell)
    path.parent.mkdir(parents=True, exist_ok=True)
    held = read_metrics(path.parent) if held_seeds and path.exists() else []
    if held and len(held[0].get("success_rate_seeds", held_seeds)) == len(held_seeds):
        rows = merge_curves([(held_seeds, held), (seeds, read_metrics(run_dir))])
        path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    else:  # the first part, or a held curve of other seeds than the record's: this part's
        shutil.copyfile(run_dir / "metrics.jsonl", path)


def _seconds_left(deadline: float | None) -> float | None:
    """Seconds until `deadline` (a `time.monotonic()` value), at least 0; None: no limit."""
    return None if deadline is None else max(0.0, deadline - time.monotonic())


def _out_of_time(deadline: float | None) -> bool:
    """Past `deadline`, as process 0's clock says: in a job of several processes every process
    takes the same decision (else some would wait in a collective that others skipped)."""
    if deadline is None:
        return False
    return bool(hosts.from_writer(np.bool_(time.monotonic() >= deadline)))


def training_wall(summary: dict[str, Any], fallback: float) -> float:
    """Training seconds over every session of a resumed run (the summary's steps over its
    rate, whose clock spans resumes), else `fallback`."""
    steps, rate = summary.get("env_steps_per_seed"), summary.get("env_steps_per_s")
    if steps and rate:
        return steps * summary.get("num_seeds", 1) / rate
    return fallback


def _plain(summary: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(summary, default=str))


# ---------------------------------------------------------------------------------------------
# Trajectories on the arena (the paper's trajectory figure)

#: the paper's trajectory figure: this formula (zone/finite/ind's first) on the Zone arena
TRAJECTORY_SUITE, TRAJECTORY_INDEX = "zone/finite/ind", 0
TRAJECTORY_SEED = 2026


def records_trajectories(cell: Cell) -> bool:
    """Whether `cell` draws the trajectory figure's episodes (single-agent Zone LiDAR worlds)."""
    return cell.trains and cell.env_id in ("PointLTL0-v0", "CarLTL0-v0", "AntLTL0-v0")


def record_trajectories(cell: Cell, params: Any, episodes: int = 3) -> dict[str, Any]:
    """`episodes` episodes of the trajectory formula with seed 1's parameters (`params`, seed
    axis first): the agent's xy per step, each episode's outcome, and its zones. The reset keys
    are fixed, so every method of a world meets the same layouts."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from specrl_jax import automata, specs
    from specrl_jax.benchmark import experiment
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.evaluate import record_episodes
    from specrl_jax.tasks import TaskEnv

    world, env_params = make(cell.env_id, **dict(cell.env_options))
    family = experiment.family(cell.env_id)
    method_obj = experiment.make_method(cell.method, world, env_params, family,
                                        cell.options() or None)
    options = {"suites": (TRAJECTORY_SUITE,)} if cell.method == "ltl2action" else {}
    policy = experiment.make_policy(cell.method, world, method_obj, None, family, **options)
    formulas = specs.suite(TRAJECTORY_SUITE)
    compiled = automata.stack([automata.compile_spec(f, world.propositions, alphabet=world.alphabet)
                               for f in formulas])
    keys = jax.random.split(jax.random.key(TRAJECTORY_SEED), episodes)
    one = jax.tree.map(lambda x: x[0], params)
    states, alive = jax.device_get(record_episodes(
        policy, TaskEnv(world, compiled), env_params, keys,
        jnp.full(episodes, TRAJECTORY_INDEX, jnp.int32), policy_params=one))
    xy = np.asarray(states.env_state.physics.agent_pos, np.float64)[..., :2]
    layouts = jax.device_get(jax.vmap(world.layout)(
        jax.tree.map(lambda x: x[:, 0], states.env_state)))
    out = []
    for i in range(episodes):
        steps = int(np.asarray(alive[i]).sum())
        success, violation = bool(states.success[i, -1]), bool(states.violation[i, -1])
        out.append({
            "xy": np.round(xy[i, :steps], 3).tolist(),
            "outcome": "success" if success else "violation" if violation else "timeout",
            "zone_xy": np.round(np.asarray(layouts["zone_xy"][i], np.float64), 3).tolist(),
            "zone_color": [world.propositions[int(c)] for c in layouts["zone_color"][i]],
            "zone_radius": np.round(np.asarray(layouts["zone_radius"][i], np.float64),
                                    3).tolist(),
        })
    return {"formula": formulas[TRAJECTORY_INDEX], "suite": TRAJECTORY_SUITE,
            "seed": TRAJECTORY_SEED, "params": "seed 1", "episodes": out}


# ---------------------------------------------------------------------------------------------
# The multi-agent coordinator: single-agent policies of PointLTL0 on every agent


def _action(pi: Any, deterministic: bool, key: Any) -> Any:
    return pi.mode() if deterministic else pi.sample(key)


def _genz_agent(network: Any, obs_kinds: dict[str, str], deterministic: bool = True):
    """GenZ-LTL on one agent: its reduced observation (reach / avoid LiDAR pooled) -> mode
    action (`deterministic`), else a sampled one."""
    from specrl_jax.baselines import genz

    kinds = dict(obs_kinds)

    def act(params, obs, goal, key):
        parts = genz.reduce_observation(obs, kinds, goal.reach, goal.avoid)
        return _action(network.apply(params, parts).pi, deterministic, key)

    return act


def _deepltl_agent(network: Any, obs_kinds: dict[str, str], deterministic: bool = True):
    """DeepLTL on one agent: its subgoal as a one-pair sequence over the single-agent alphabet
    (the empty label avoidable) -> mode action (`deterministic`; else sampled), the epsilon
    output dropped (the coordinator takes epsilon edges)."""
    import jax.numpy as jnp

    from specrl_jax.baselines import deepltl
    from specrl_jax.baselines.encoders import obs_parts

    kinds = dict(obs_kinds)
    split = deepltl.split_action(network)

    def act(params, obs, goal, key):
        seq = deepltl.SequenceObs(
            obs_parts(obs, kinds), goal.reach_symbols[None], goal.avoid_symbols[None],
            jnp.zeros(1, bool), jnp.int32(0), jnp.int32(1), jnp.zeros((), bool))
        return split(_action(network.apply(params, seq).pi, deterministic, key))[0]

    return act


def evaluate_coordinator(cell: Cell, params: Any, suites: Sequence[str], log: Log,
                         deterministic: bool = True, horizon: int | None = None) -> list:
    """The coordinator cell's suites: the `params_from` cell's network (seed-1 `params`, seed
    axis of 1) on every agent of `cell.env_id`, each evaluation seed running those parameters;
    mode actions (`deterministic`, docs/fidelity.md), else sampled ones (GenZ-LTL and DeepLTL).
    `horizon` overrides every suite's episode length (smoke runs)."""
    import warnings

    import jax
    import numpy as np

    from specrl_jax import specs
    from specrl_jax.baselines import gcrl
    from specrl_jax.benchmark import experiment
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.suites import evaluate_suites
    from specrl_jax.tasks.coordinator import SystemWorld, check_spec_agents, make_coordinator

    source = Store().trained_as(grid.cell(cell.params_from))
    if not deterministic and source.method == "gcrl":
        raise ValueError("GCRL-LTL's coordinator agent acts on its primitives' mode actions only")
    env, env_params = make(cell.env_id)
    single, single_params = make(source.env_id)
    if not np.array_equal(np.asarray(single.alphabet), np.asarray(env.world.alphabet)):
        raise ValueError(f"{source.env_id}'s alphabet differs from {cell.env_id}'s agents'")
    for name in suites:
        for formula in specs.suite(name):
            check_spec_agents(formula, env)
    method_obj = experiment.make_method(source.method, single, single_params,
                                        experiment.family(source.env_id), source.options() or None)
    builders = {"genz": _genz_agent, "deepltl": _deepltl_agent, "gcrl": gcrl.coordinator_agent}
    sampling = {} if deterministic else {"deterministic": False}
    policy = make_coordinator(
        builders[source.method](method_obj.network, single.obs_kinds, **sampling), env)
    one = jax.device_put(jax.tree.map(lambda x: x[0], params))
    with warnings.catch_warnings():  # three specs exceed the candidate caps (fidelity.md)
        warnings.filterwarnings("ignore", message=".*candidate sequences dropped")
        return evaluate_suites(policy, cell.env_id, SystemWorld(env), env_params, suites,
                               cell.episodes, seeds=range(1, cell.seeds + 1), policy_params=one,
                               horizon=horizon, label=f"{source.method} + coordinator", log=log)


# ---------------------------------------------------------------------------------------------
# A selection of cells


def gpu_count() -> int:
    """GPUs visible to this process, without initialising JAX (which would hold them all)."""
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is not None:
        return len([d for d in visible.split(",") if d.strip() and d.strip() != "-1"])
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=30,
                             check=False)
    except (OSError, subprocess.SubprocessError):
        return 0
    return sum(line.startswith("GPU ") for line in out.stdout.splitlines())


def shrink(cells: Sequence[Cell], **changes: Any) -> list[Cell]:
    """The cells with `seeds`, `total_steps`, `episodes` or `ppo` replaced (None: kept), for
    smoke runs into a scratch store."""
    changes = {k: v for k, v in changes.items() if v is not None}
    if "ppo" in changes:
        changes["ppo"] = tuple(sorted(changes["ppo"].items()))
    return [dataclasses.replace(c, **changes) for c in cells]


def format_list(cells: Sequence[Cell], store: Store | None = None) -> str:
    """The grid with each cell's state and estimated GPU time (a partial cell's: that of the
    seeds it lacks, trained as one part with `--seed-range`; without it the cell is retrained
    whole). A state marked `*` was trained with PPO settings since replaced
    (`store.legacy_settings`)."""
    store = store or Store()
    rows = [f"{'cell':44s} {'step':>4s} {'state':8s} {'seeds':>5s} {'est. GPU':>9s}"]
    todo, rates, legacy = 0.0, estimate.measured_rates(), 0
    for c in cells:
        state = store.state(c)
        record = store.read(c)
        seeds = suite_seeds(record) if record else 0
        left = c.seeds - seeds if state == "partial" and 0 < seeds < c.seeds else c.seeds
        seconds = estimate.seconds(dataclasses.replace(c, seeds=left), rates)
        if state != "done":
            todo += seconds
        marked = bool(record and c.trains and legacy_settings(c, record))
        legacy += marked
        rows.append(f"{c.name:44s} {c.step:4d} {state + '*' * marked:8s} "
                    f"{f'{seeds}/{c.seeds}':>5s} {_duration(seconds):>9s}")
    done = sum(store.state(c) == "done" for c in cells)
    rows.append(f"{len(cells)} cells: {done} done, {len(cells) - done} to run, "
                f"about {_duration(todo)} of GPU time (one GPU; partial cells completed with "
                "--seed-range)")
    if legacy:
        settings = ", ".join(f"{k}={v}" for k, v in LEGACY_PPO.items())
        rows.append(f"* {legacy} cell{'s' * (legacy > 1)} trained with PPO settings since "
                    f"replaced ({settings}; docs/fidelity.md); --rerun trains one again")
    return "\n".join(rows)


def _duration(seconds: float) -> str:
    minutes = seconds / 60
    return f"{minutes:.0f} min" if minutes < 120 else f"{minutes / 60:.1f} h"


def discard(cell: Cell, store: Store) -> None:
    """Forget `cell`'s results and run directory in `store` (git keeps committed ones)."""
    (store.cell_dir(cell) / "cell.json").unlink(missing_ok=True)
    shutil.rmtree(store.scratch_dir(cell), ignore_errors=True)


def reproduce(patterns: str | Sequence[str] | None = None, store: Store | None = None,
              log: Log = print, gpus: int | None = None, cells: Sequence[Cell] | None = None,
              worker_args: Sequence[str] = (), rerun: bool = False,
              max_minutes: float | None = None, cells_per_gpu: int = 1,
              **run_options: Any) -> dict[str, str]:
    """Run the selected cells (`grid.select(patterns)`, or `cells`); returns `{name: state}`.
    `rerun` discards what the store holds of them first, so they run end to end. After
    `max_minutes` no cell or evaluation starts and training stops at its next checkpoint
    (every 10 updates), so a run fits a time slot and the same command resumes it. A cell that
    fails is logged with its error and the next one runs (as side by side). In a job of
    several processes (`hosts.join`) the cells run in turn (`gpus` None or 1), each over every
    process's devices; process 0 writes and logs. `cells_per_gpu` subprocesses share each GPU
    (module docstring). `run_options` go to `run_cell`; with
    `part` (seed numbers) the states are those of the part's seeds, and a cell whose part cannot
    be trained (`part_problem`) is skipped."""
    deadline = None if max_minutes is None else time.monotonic() + 60.0 * max_minutes
    store = store or Store()
    chosen = list(cells) if cells is not None else grid.select(patterns)
    if not isinstance(cells_per_gpu, int) or cells_per_gpu < 1:
        raise ValueError(f"cells_per_gpu is a count of cells sharing one GPU (>= 1); got "
                         f"{cells_per_gpu!r}")
    if hosts.joined():
        if gpus not in (None, 1) or cells_per_gpu != 1:
            raise ValueError("--gpus and --cells-per-gpu run cells side by side on one host; a job of several "
                             "processes trains each cell over every process's devices, one cell "
                             "after the other: leave --gpus out")
        gpus, log = 1, hosts.writer_log(log)
    if rerun:
        for c in chosen:
            log(f"{c.name}: discarding its stored results to run it again")
            if hosts.is_writer():
                discard(c, store)
    hosts.barrier("store ready")  # every process reads the store as process 0 left it
    part = run_options.get("part")
    problems = {c.name: part_problem(c, store, part) for c in chosen}
    for problem in filter(None, problems.values()):
        log(f"{problem}: skipped")

    def state(c: Cell) -> str:  # of the part's seeds, with a part
        if part is None or problems[c.name]:
            return store.state(c)
        return "done" if not missing_work(c, store.read(c) or {}, part) else "partial"

    todo = [c for c in chosen if state(c) != "done" and not problems[c.name]]
    for c in chosen:
        if state(c) == "done":
            log(f"{c.name}: done, skipped")
    if not todo:
        return {c.name: state(c) for c in chosen}
    gpus = gpu_count() if gpus is None else gpus
    slots = max(gpus, 1) * cells_per_gpu
    rates = estimate.measured_rates()  # a part's estimate: that many seeds
    estimates = {c.name: estimate.seconds(dataclasses.replace(c, seeds=len(part)) if part else c,
                                          rates) for c in todo}
    total = sum(estimates.values())
    log(f"{len(todo)} cells to run, about {_duration(total)} of GPU time"
        + (f", {slots} side by side on {max(gpus, 1)} GPU{'s' if gpus > 1 else ''}"
           if slots > 1 else ""))
    if slots > 1 and len(todo) > 1:
        _run_side_by_side(todo, estimates, store, max(gpus, 1), log, worker_args, deadline,
                          cells_per_gpu)
    else:
        spent, estimated = 0.0, 0.0
        for i, c in enumerate(todo):
            if _out_of_time(deadline):
                log(f"time limit reached: {', '.join(x.name for x in todo[i:])} not started; "
                    "rerun the same command to resume")
                break
            start = time.perf_counter()
            try:
                run_cell(c, store, log=lambda line, c=c: log(f"[{c.name}] {line}"),
                         deadline=deadline, **run_options)
            except Exception as err:  # the other cells go on, as side by side
                if hosts.joined():
                    raise  # every process must leave the cell together
                log(f"[{c.name}] failed, {store.state(c)}: {type(err).__name__}: {err}\n"
                    + "".join(traceback.format_exception(err)).rstrip())
            spent += time.perf_counter() - start
            estimated += estimates[c.name]
            rest = sum(estimates[x.name] for x in todo[i + 1:])
            left = rest * spent / max(estimated, 1e-9)
            log(f"{i + 1}/{len(todo)} cells finished in {_duration(spent)}; ETA {_duration(left)}")
    return {c.name: state(c) for c in chosen}


def _run_side_by_side(cells: Sequence[Cell], estimated: dict[str, float], store: Store,
                      gpus: int, log: Log, worker_args: Sequence[str],
                      deadline: float | None = None, cells_per_gpu: int = 1) -> None:
    """One subprocess per cell, at most `cells_per_gpu` per GPU at a time (each then given that
    share of the memory one process takes), none started after `deadline` (each is given the
    minutes left); their output is prefixed with the cell's name. `estimated`: each cell's
    estimated seconds, for the ETA."""
    import threading

    queue = list(cells)
    running: dict[int, tuple[subprocess.Popen, Cell, float]] = {}
    finished, spent, done_estimate = 0, 0.0, 0.0
    start_all = time.perf_counter()

    def pump(proc: subprocess.Popen, name: str) -> None:
        for line in proc.stdout:
            log(f"[{name}] {line.rstrip()}")

    slots = gpus * cells_per_gpu
    while queue or running:
        for slot in range(slots):  # slot s on GPU s % gpus: every GPU takes a cell before any two
            gpu = slot % gpus
            left = _seconds_left(deadline)
            if left == 0.0 and queue:
                log(f"time limit reached: {', '.join(x.name for x in queue)} not started; "
                    "rerun the same command to resume")
                queue.clear()
            if slot not in running and queue:
                c = queue.pop(0)
                env = dict(os.environ, CUDA_VISIBLE_DEVICES=str(gpu))
                if cells_per_gpu > 1:
                    env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{memory_share(cells_per_gpu):.3f}"
                limit = [] if left is None else ["--max-minutes", f"{left / 60.0:.3f}"]
                cmd = [sys.executable, "-m", "specrl_jax.benchmark.reproduce", "--cells", c.name,
                       "--store", str(store.root), "--gpus", "1", *worker_args, *limit]
                proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)
                threading.Thread(target=pump, args=(proc, c.name), daemon=True).start()
                running[slot] = (proc, c, time.perf_counter())
                log(f"{c.name}: started on GPU {gpu}")
        time.sleep(2.0)
        for slot, (proc, c, began) in list(running.items()):
            if proc.poll() is None:
                continue
            del running[slot]
            finished += 1
            spent += time.perf_counter() - began
            done_estimate += estimated[c.name]
            left = sum(estimated[x.name] for x in queue) + sum(
                estimated[r[1].name] for r in running.values())
            eta = left * spent / max(done_estimate, 1e-9) / slots
            log(f"{c.name}: exit {proc.returncode}, {store.state(c)}; {finished}/{len(cells)} "
                f"cells after {_duration(time.perf_counter() - start_all)}; ETA {_duration(eta)}")


def memory_share(cells_per_gpu: int) -> float:
    """The fraction of a GPU's memory that JAX takes in each of `cells_per_gpu` processes
    sharing it: XLA_PYTHON_CLIENT_MEM_FRACTION's default (0.75) split between them, so that
    MuJoCo Warp's own allocations keep the room they have beside one process; the caller's
    XLA_PYTHON_CLIENT_MEM_FRACTION, when set, is split instead."""
    total = float(os.environ.get("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.75"))
    return total / cells_per_gpu


def main(argv: Sequence[str] | None = None) -> int:
    """`specrl-jax reproduce` (also `python -m specrl_jax.benchmark.reproduce`)."""
    parser = argparse.ArgumentParser(prog="specrl-jax reproduce",
                                     description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run_from_args(parser.parse_args(argv))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from specrl_jax.cli import SEED_RANGE_HELP, seed_range

    parser.add_argument("--cells", default=None,
                        help="fnmatch pattern(s) of cell names, comma-separated (default: all), "
                             "e.g. 'LetterLTL0-v0/genz' or 'Panda*/*'")
    parser.add_argument("--list", action="store_true", help="show the grid, states and estimates")
    parser.add_argument("--store", default=None,
                        help="results store directory (default: the package's)")
    parser.add_argument("--gpus", type=int, default=None,
                        help="cells side by side (default: the visible GPUs; 1: in turn)")
    parser.add_argument("--cells-per-gpu", type=int, default=1, metavar="K",
                        help="run K cells side by side on each GPU, each process with 1/K of "
                             "the memory one would take (default 1); for cells whose steps "
                             "leave the GPU idle between kernel launches")
    parser.add_argument("--seeds", type=int, default=None,
                        help="seeds per cell (default 5): fewer for smoke runs")
    parser.add_argument("--seed-range", type=seed_range, default=None, metavar="FIRST-LAST",
                        help=SEED_RANGE_HELP)
    parser.add_argument("--total-steps", type=int, default=None,
                        help="smoke runs: env steps per seed")
    parser.add_argument("--episodes", type=int, default=None,
                        help="smoke runs: episodes per spec and seed")
    parser.add_argument("--num-envs", type=int, default=None, help="smoke runs: envs per seed")
    parser.add_argument("--rerun", action="store_true",
                        help="discard the selected cells' stored results and run them again")
    parser.add_argument("--max-minutes", type=float, default=None,
                        help="stop cleanly after this many minutes: training checkpoints at its "
                             "next chunk, no further cell starts, nor an evaluation "
                             "estimated to end past them; the same command resumes "
                             "(default: no limit)")


def run_from_args(args: argparse.Namespace) -> int:
    store = Store(args.store)
    ppo = {"num_envs": args.num_envs} if args.num_envs else None
    cells = shrink(grid.select(args.cells), seeds=args.seeds, total_steps=args.total_steps,
                   episodes=args.episodes, ppo=ppo)
    if args.list:
        print(format_list(cells, store))
        return 0
    from specrl_jax import cache

    cache.enable_jax_cache()
    worker = []
    for flag, value in (("--seeds", args.seeds), ("--total-steps", args.total_steps),
                        ("--episodes", args.episodes), ("--num-envs", args.num_envs)):
        if value is not None:
            worker += [flag, str(value)]
    part = getattr(args, "seed_range", None)
    if part is not None:
        worker += ["--seed-range", f"{part[0]}-{part[-1]}"]
    states = reproduce(cells=cells, store=store, gpus=args.gpus, worker_args=worker,
                       rerun=getattr(args, "rerun", False), part=part,
                       cells_per_gpu=getattr(args, "cells_per_gpu", 1),
                       max_minutes=getattr(args, "max_minutes", None),
                       log=lambda line: print(line, flush=True))
    incomplete = [n for n, s in states.items() if s != "done"]
    hosts.writer_log(print)(f"{len(states) - len(incomplete)}/{len(states)} cells done"
                            + (f"; not done: {', '.join(incomplete)}" if incomplete else ""))
    return 0 if not incomplete else 1


if __name__ == "__main__":
    sys.exit(main())
