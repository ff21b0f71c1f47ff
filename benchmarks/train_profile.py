"""What bounds a training loop: seconds per PPO update, split into its rollout and its PPO step.

The training is built as `specrl-jax train` builds it (`experiment.build` with the family's shape
on this device kind, `experiment.default_overrides`, and its reset bank, `WorldFamily.map_bank_size`;
`runs.init_seeds`); the method's phase before PPO (GCRL-LTL's primitives, LTL2Action's
pretraining) is left out, its placeholders having the trained shapes. After a warm-up call
(compilation timed apart) each part is timed over `--updates` updates with `block_until_ready`,
median of `--repeats` (`--parallel-compile` compiles the update and full programs side by side):

  rollout  `Trainer.collect`: `num_steps` env steps and policy inferences in `num_envs` envs
  update   `Trainer.learn` on one stored rollout: advantages, then epochs x minibatches of
           gradient steps (fewer epochs when the KL stop fires; the same rollout every call, so
           the same epochs)
  full     the training's own compiled chunk (`runs.seed_batched`, the `--updates` updates in one
           scan), as `runs.train_chunks` calls it
  host     what the training loop does on the host after each chunk of updates (10 in
           `specrl-jax train`): the metrics' `device_get` and the checkpoint's write

Seeds run side by side as in training (`vmap`; one seed unbatched; `--learn-in-turn`: the
update part and the full step's learning one seed after the other). Rates count every seed's env
steps (`seeds x num_envs x num_steps` per update); gradient steps are per seed (seeds take theirs
side by side). Each compiled program is described from `compile().as_text()`: HLO instructions,
fusions and custom calls (about the kernels an accelerator launches), `while` loops with and
without a known trip count (on a GPU each iteration of one without copies its predicate to the
host: a host sync; `while_loop_sources` names the `lax.while_loop`s), host callbacks, and
`cost_analysis` flops and bytes (loop bodies counted once). A table is printed and one JSON row
(`harness.row`) appended to `--out`. `--kernels N` traces one rollout and one PPO step with JAX's
profiler and adds their kernel launches, kernel time and N longest kernels (by HLO instruction;
kernels XLA runs inside CUDA graphs, its command buffers, count as launched one by one).

`--devices 1 2 ...` profiles the training over the first N local devices for each N, the env batch
sharded over them as `specrl-jax train` shards it; the default env count per seed grows with N
(weak scaling: `--num-envs`, or the family's shape, per device). It then prints each N's
efficiency, its rate over the first count's rate scaled by N over that count, and adds a row of
them; `--plot PNG` draws them (rate and seconds per update against N), `--plot-rows JSONL --plot
PNG` draws them from the rows of an earlier `--out`.

    python benchmarks/train_profile.py --env LetterLTL0-v0 --method genz --seeds 5 --updates 5
    python benchmarks/train_profile.py --env PointLTL0Vision-v0 --env-option image_size=64 --seeds 5
    python benchmarks/train_profile.py --env PointLTL0-v0 --seeds 5 --devices 1 2 --plot s.png
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import jax.numpy as jnp
from jax._src import source_info_util  # names a loop's user frame; no public equivalent

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import harness

from specrl_jax import families
from specrl_jax.baselines import runs
from specrl_jax.baselines.ppo import env_mesh, make_train
from specrl_jax.benchmark import experiment

METHODS = ("genz", "deepltl", "ltl2action", "gcrl", "rad")
# an HLO instruction's op: the first `name(` after `=` (shapes hold no such token)
_OP = re.compile(r"=\s.*?\s([a-z][\w\-]*)\(")
_TARGET = re.compile(r'custom_call_target="([^"]+)"')
_SOURCE = re.compile(r'source_file="([^"]+)" source_line=(\d+)')
_NAME = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+) = ")
#: cross-device operations (and their asynchronous starts) in the partitioned program
COLLECTIVES = ("all-gather", "all-to-all", "all-reduce", "collective-permute", "reduce-scatter")


def _short(path: str) -> str:
    """A source path from its package folder on (`site-packages/...`, `specrl_jax/...`)."""
    return re.sub(r"^.*/(site-packages|specrl_jax)/", r"\1/", path)


def program_stats(compiled: Any) -> dict[str, Any]:
    """Size and structure of a compiled program (its HLO text after optimisation)."""
    ops: collections.Counter = collections.Counter()
    targets: collections.Counter = collections.Counter()
    collective_sources: collections.Counter = collections.Counter()
    whiles = known = 0
    for line in compiled.as_text().splitlines():
        match = _OP.search(line)
        if not match or line.lstrip().startswith(("HloModule", "//")):
            continue
        op = match.group(1)
        ops[op] += 1
        if op == "while":
            whiles += 1
            known += "known_trip_count" in line
        elif op == "custom-call":
            target = _TARGET.search(line)
            targets[target.group(1) if target else "?"] += 1
        elif op.removesuffix("-start") in COLLECTIVES:
            where = _SOURCE.search(line)
            where = f"{_short(where.group(1))}:{where.group(2)}" if where else "?"
            collective_sources[f"{op.removesuffix('-start')} {where}"] += 1
    callbacks = sum(n for t, n in targets.items() if "callback" in t.lower())
    stats = {
        "hlo_instructions": sum(ops.values()),
        "fusions": ops["fusion"],
        "custom_calls": ops["custom-call"],
        "custom_call_targets": dict(targets.most_common(8)),
        "while_loops": whiles,
        "while_loops_unknown_trip_count": whiles - known,
        "conditionals": ops["conditional"],
        "collectives": {op: ops[op] + ops[f"{op}-start"] for op in COLLECTIVES
                        if ops[op] + ops[f"{op}-start"]},
        "collective_sources": dict(collective_sources.most_common(12)),
        "host_transfers": callbacks + sum(ops[o] for o in ("outfeed", "infeed", "send", "recv")),
        "top_ops": dict(ops.most_common(8)),
    }
    cost = compiled.cost_analysis()  # None, a dict, or (older JAX) a list of one dict
    cost = cost[0] if isinstance(cost, (list, tuple)) and cost else cost
    if isinstance(cost, dict):
        stats["flops"] = float(cost.get("flops", 0.0))
        stats["bytes_accessed"] = float(cost.get("bytes accessed", 0.0))
    return stats


def timed(fn: Callable[[], Any], repeats: int) -> list[float]:
    """Wall seconds of `repeats` calls of `fn` (each blocks until its result is ready)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return times


def log(line: str) -> None:
    """Progress on stderr, so that a run stopped at a time limit still shows how far it got."""
    print(line, file=sys.stderr, flush=True)


def build(args: argparse.Namespace, num_devices: int) -> tuple[Any, Any, dict[str, Any]]:
    """(trainer, per-seed key, notes) as `specrl-jax train` builds them, the env batch sharded
    over the first `num_devices` local devices, `--num-envs` (or the family's) on each."""
    platform = jax.devices()[0].platform
    world_family = experiment.family(args.env)
    images = experiment.observes_images(args.env, dict(args.env_option))
    overrides = experiment.default_overrides(platform, None, world_family, args.method, images)
    num_envs = (args.num_envs or overrides["num_envs"]) * num_devices
    overrides.update({k: v for k, v in (
        ("num_envs", num_envs), ("num_steps", args.num_steps),
        ("num_minibatches", args.minibatches), ("update_epochs", args.epochs)) if v is not None})
    if args.learn_in_turn is not None:
        overrides["learn_seeds_in_turn"] = args.learn_in_turn == "on"
    map_bank = (families.get(world_family).map_bank_size(platform) if args.map_bank is None
                else args.map_bank)
    key_bank, key_train = jax.random.split(jax.random.key(args.seed))
    start = time.perf_counter()
    world, _, method_obj, config = experiment.build(
        args.method, args.env, overrides, map_bank or None, key_bank, args.env_option,
        args.method_option)
    experiment.warn_slow_camera(world, platform)
    notes = {"map_bank": map_bank, "setup_s": round(time.perf_counter() - start, 2),
             "physics": getattr(getattr(world, "physics", None), "backend", None),
             "devices": num_devices}
    mesh = env_mesh(jax.local_devices()[:num_devices])
    return make_train(config, method_obj, mesh), key_train, notes


def compile_parts(trainer: Any, runner: Any, seeds: int, n: int, parallel: bool
                  ) -> tuple[dict[str, Any], dict[str, float], dict[str, dict[str, int]]]:
    """The rollout, update and full-step programs compiled for `runner` (seed axis first), each
    one's seconds to trace and compile, and each one's `while_sources`."""

    def rollout(runner):
        key, key_collect, _ = jax.random.split(runner.key, 3)
        env_state, obs, traj = trainer.collect(runner, key_collect)
        return runner.replace(env_state=env_state, obs=obs, key=key), traj

    def learn(runner, traj):
        _, _, key_epochs = jax.random.split(runner.key, 3)
        return trainer.learn(runner.params, runner.opt_state, traj, runner.obs, key_epochs)

    def learn_in_turn(runners, trajs):
        return jax.lax.map(lambda args: learn(*args), (runners, trajs))

    lowered, seconds, loops, programs = {}, {}, {}, {}

    def compile_part(part: str) -> Any:
        start = time.perf_counter()
        program = lowered[part].compile()
        seconds[part] += time.perf_counter() - start
        log(f"compiled the {part} program in {seconds[part]:.1f} s")
        return program

    for part, fn, inputs, options in (  # tracing holds the GIL: one program at a time
            ("rollout", runs.over_seeds(rollout, seeds), (runner,), {"donate_argnums": 0}),
            ("update", learn_in_turn if trainer.config.learn_seeds_in_turn and seeds > 1
             else runs.over_seeds(learn, seeds), None, {}),
            ("full", runs.seed_batched(trainer, seeds), (runner, n, jnp.int32(1)),
             {"static_argnums": 1, "donate_argnums": 0})):
        start = time.perf_counter()
        if inputs is None:  # the stored rollout, laid out over the devices as the rollout's
            programs["rollout"] = compile_part("rollout")
            traj = jax.tree.map(lambda info, sharding: jax.ShapeDtypeStruct(
                info.shape, info.dtype, sharding=sharding), lowered["rollout"].out_info[1],
                programs["rollout"].output_shardings[1])
            inputs = (runner, traj)
            start = time.perf_counter()
        traced = jax.jit(fn, **options).trace(*inputs)
        lowered[part] = traced.lower()
        seconds[part] = seconds.get(part, 0.0) + time.perf_counter() - start
        loops[part] = while_sources(traced.jaxpr.jaxpr)

    rest = [part for part in lowered if part not in programs]
    with ThreadPoolExecutor(len(rest) if parallel else 1) as pool:
        programs.update(zip(rest, pool.map(compile_part, rest)))
    return {part: programs[part] for part in lowered}, seconds, loops


def while_sources(jaxpr: Any, found: collections.Counter | None = None) -> dict[str, int]:
    """Where the program's `lax.while_loop`s are (source line -> count), nested ones included:
    the loops whose trip count depends on data (scans are not among them; XLA may still find
    the count of some)."""
    found = collections.Counter() if found is None else found
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "while":
            where = source_info_util.summarize(eqn.source_info)
            found[_short(where)] += 1
        for param in eqn.params.values():
            for sub in param if isinstance(param, (list, tuple)) else (param,):
                inner = getattr(sub, "jaxpr", sub)  # a ClosedJaxpr's Jaxpr, or a Jaxpr
                if hasattr(inner, "eqns"):
                    while_sources(inner, found)
    return dict(found)


def time_parts(compiled: dict[str, Any], runner: Any, n: int, repeats: int
               ) -> tuple[dict[str, list[float]], Any, Any, Any]:
    """Seconds of `repeats` calls of `n` updates of each part, after a warm-up call; returns
    them, the update part's epochs `[seeds]`, the full step's metrics and its final state."""
    runner, traj = jax.block_until_ready(compiled["rollout"](runner))  # warm-up

    def rollouts():
        nonlocal runner, traj
        for _ in range(n):
            runner, traj = compiled["rollout"](runner)
        jax.block_until_ready(traj)

    seconds = {"rollout": timed(rollouts, repeats)}
    log(f"rollout: {statistics.median(seconds['rollout']) / n:.4f} s per update")
    kept = (runner, traj)
    epochs = jax.block_until_ready(compiled["update"](*kept))[3]  # warm-up

    def updates():
        for _ in range(n):
            out = compiled["update"](*kept)
        jax.block_until_ready(out)

    seconds["update"] = timed(updates, repeats)
    log(f"update: {statistics.median(seconds['update']) / n:.4f} s per update")
    traj = kept = None  # frees the stored rollout before the full step
    metrics = None

    def full():
        nonlocal runner, metrics
        runner, metrics = jax.block_until_ready(compiled["full"](runner, jnp.int32(n)))

    full()  # warm-up
    seconds["full"] = timed(full, repeats)
    log(f"full step: {statistics.median(seconds['full']) / n:.4f} s per update")
    return seconds, jax.device_get(epochs), metrics, runner


def profiler_events(fn: Callable[[], Any]) -> list[dict[str, Any]]:
    """The events of one call of `fn` under JAX's profiler (its Perfetto trace)."""
    with tempfile.TemporaryDirectory() as directory:
        with jax.profiler.trace(directory, create_perfetto_trace=True):
            jax.block_until_ready(fn())
        (path,) = glob.glob(os.path.join(directory, "**", "perfetto_trace.json.gz"), recursive=True)
        with gzip.open(path) as f:
            trace = json.load(f)
    return trace["traceEvents"] if isinstance(trace, dict) else trace


def complete_events(events: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], dict[Any, str]]:
    """A trace's complete events, its process names by pid and thread names by (pid, tid)."""
    names = {e["pid"] if e["name"] == "process_name" else (e["pid"], e.get("tid")): e["args"]["name"]
             for e in events if e.get("ph") == "M" and e.get("name") in ("process_name", "thread_name")}
    return [e for e in events if e.get("ph") == "X"], names


def kernel_times(fn: Callable[[], Any], compiled: Any, top: int) -> dict[str, Any]:
    """Where one call of a compiled part spends device time: its kernels (on an accelerator, the
    events on the `Stream #` threads of the `/device:` processes less copies and memsets; on the
    CPU, the events named after the program's HLO instructions, less the loops and calls that
    hold others) summed by name, the `top` longest with their milliseconds and launches, their
    total and the number of launches."""
    events, names = complete_events(profiler_events(fn))
    devices = {pid for pid, name in names.items() if str(name).startswith("/device:")}
    if devices:
        kernels = [e for e in events if e["pid"] in devices
                   and names.get((e["pid"], e.get("tid")), "").startswith("Stream #")
                   and not e["name"].startswith(("Memcpy", "Memset"))]
    else:
        names = {name.group(1) for line in compiled.as_text().splitlines()
                 if (name := _NAME.match(line)) and (op := _OP.search(line))
                 and op.group(1) not in ("while", "conditional", "call")}
        kernels = [e for e in events if e["name"] in names]
    ms: collections.Counter = collections.Counter()
    launches: collections.Counter = collections.Counter()
    for e in kernels:
        name = (e.get("args") or {}).get("hlo_op") or e["name"]
        ms[name] += e.get("dur", 0.0) / 1e3
        launches[name] += 1
    return {"kernel_ms": round(sum(ms.values()), 3), "launches": sum(launches.values()),
            "top": [[name, round(t, 3), launches[name]] for name, t in ms.most_common(top)]}


def part_kernels(compiled: dict[str, Any], runner: Any, top: int) -> dict[str, Any]:
    """`kernel_times` of one update's rollout and of one PPO step on its rollout (the rollout
    donates `runner`)."""
    stored = ()

    def rollout():
        nonlocal stored
        stored = compiled["rollout"](runner)
        return stored

    return {"rollout": kernel_times(rollout, compiled["rollout"], top),
            "update": kernel_times(lambda: compiled["update"](*stored), compiled["update"], top)}


def host_work(metrics: Any, runner: Any, repeats: int) -> dict[str, float]:
    """The training loop's host work after a chunk: the metrics' copy, the checkpoint's write."""
    host = {"metrics_get_s": min(timed(lambda: jax.device_get(metrics), repeats))}
    with tempfile.TemporaryDirectory() as directory:
        path = os.path.join(directory, runs.CHECKPOINT)
        host["checkpoint_s"] = min(timed(lambda: runs.save_checkpoint(path, runner), repeats))
        host["checkpoint_bytes"] = os.path.getsize(path)
    return host


def profile(args: argparse.Namespace, num_devices: int = 1) -> dict[str, Any]:
    """The profile's JSON fields for `args` over the first `num_devices` local devices."""
    trainer, key, notes = build(args, num_devices)
    cfg, seeds, n = trainer.config, args.seeds, args.updates
    start = time.perf_counter()
    runner = jax.block_until_ready(runs.init_seeds(trainer, key, seeds))
    notes["init_s"] = round(time.perf_counter() - start, 2)
    log(f"set up in {notes['setup_s']:.1f} s, initial state in {notes['init_s']:.1f} s")
    start = time.perf_counter()
    compiled, compile_s, loops = compile_parts(trainer, runner, seeds, n, args.parallel_compile)
    notes["compile_wall_s"] = round(time.perf_counter() - start, 2)
    seconds, epochs, metrics, runner = time_parts(compiled, runner, n, args.repeats)
    host = host_work(metrics, runner, args.repeats)
    kernels = part_kernels(compiled, runner, args.kernels) if args.kernels else None

    per_update = {part: statistics.median(t) / n for part, t in seconds.items()}
    steps = seeds * cfg.batch_size
    grad_steps = float(epochs.max()) * cfg.num_minibatches  # seeds side by side: the most
    full_epochs = jax.device_get(metrics["epochs"])  # [seeds, n]
    # the full step's epochs are its own rollouts' (the KL stop): the parts at those epochs
    split_s = per_update["rollout"] + per_update["update"] / float(epochs.max()) * float(
        full_epochs.max(axis=0).mean())
    programs = {part: {**program_stats(c), "while_loop_sources": loops[part]}
                for part, c in compiled.items()}
    return {
        "env": args.env, "method": args.method, "seeds": seeds, "num_envs": cfg.num_envs,
        "num_steps": cfg.num_steps, "num_minibatches": cfg.num_minibatches,
        "minibatch_size": cfg.minibatch_size, "update_epochs": cfg.update_epochs,
        "target_kl": cfg.target_kl, "updates": n, "repeats": args.repeats,
        "env_options": args.env_option, "method_options": args.method_option, **notes,
        **{f"{part}_s": s for part, s in per_update.items()},
        **{f"{part}_steps_per_s": steps / s for part, s in per_update.items()},
        "rollout_share": per_update["rollout"] / (per_update["rollout"] + per_update["update"]),
        "split_s": split_s,
        "epochs": float(epochs.mean()), "epochs_per_seed": [int(e) for e in epochs],
        "full_epochs_per_seed": full_epochs.tolist(),
        "update_s_per_epoch": per_update["update"] / float(epochs.max()),
        "grad_steps_per_update": grad_steps, "grad_steps_per_s": grad_steps / per_update["update"],
        "compile_s": {part: round(s, 2) for part, s in compile_s.items()},
        "parallel_compile": args.parallel_compile,
        "learn_in_turn": trainer.config.learn_seeds_in_turn,
        "compilation_cache": jax.config.jax_compilation_cache_dir,
        "seconds_per_repeat": seconds, "host_per_chunk": host,
        "host_syncs_per_update_min": host_syncs(programs, cfg.num_steps, full_epochs),
        "programs": programs,
        **({"kernels": kernels} if kernels else {}),
    }


def host_syncs(programs: dict[str, dict[str, Any]], num_steps: int, full_epochs: Any) -> float:
    """A lower bound of the host syncs of one update on a GPU, where each `conditional` and
    each iteration of a `while` without a known trip count copies a predicate to the host: the
    full step's conditionals, the rollout's such loops once per step, and the KL stop's loop
    once per epoch and once to stop (from this device's programs)."""
    rollout, update = programs["rollout"], programs["update"]
    syncs = programs["full"]["conditionals"] + rollout["while_loops_unknown_trip_count"] * num_steps
    if update["while_loops_unknown_trip_count"]:
        syncs += float(full_epochs.max(axis=0).mean()) + 1
    return syncs


def table(result: dict[str, Any]) -> str:
    r = result
    title = (f"{r['env']} {r['method']}: {r['seeds']} seed(s) x {r['num_envs']} envs x "
             f"{r['num_steps']} steps, {r['num_minibatches']} minibatches of "
             f"{r['minibatch_size']}, epochs {r['epochs']:g} of {r['update_epochs']}")
    header = (f"{'part':8} {'s/update':>10} {'env-steps/s':>13} {'compile s':>10} {'HLO ops':>8} "
              f"{'fusions':>8} {'whiles (unknown trips)':>23}")
    lines = [title, header]
    for part in ("rollout", "update", "full"):
        p = r["programs"][part]
        lines.append(f"{part:8} {r[part + '_s']:10.4f} {r[part + '_steps_per_s']:13,.0f} "
                     f"{r['compile_s'][part]:10.1f} {p['hlo_instructions']:8} {p['fusions']:8} "
                     f"{p['while_loops']:>12} ({p['while_loops_unknown_trip_count']})")
    host = r["host_per_chunk"]
    lines.append(f"rollout + update at the full step's epochs {r['split_s']:.4f} s; at least "
                 f"{r['host_syncs_per_update_min']:g} host syncs per update on a GPU")
    lines.append(f"rollout share {r['rollout_share']:.0%}; {r['grad_steps_per_s']:,.0f} gradient "
                 f"steps/s per seed; host per chunk: metrics {host['metrics_get_s'] * 1e3:.1f} ms, "
                 f"checkpoint {host['checkpoint_s'] * 1e3:.1f} ms "
                 f"({host['checkpoint_bytes'] / 2**20:.1f} MiB)")
    for part, k in (r.get("kernels") or {}).items():
        lines.append(f"{part}: {k['launches']} kernel launches, {k['kernel_ms']:.2f} ms of kernels; "
                     "the longest (ms, launches):")
        lines += [f"  {ms:9.3f} {n:6}  {name[:90]}" for name, ms, n in k["top"]]
    return "\n".join(lines)


def _option(pair: str) -> tuple[str, Any]:
    key, sep, value = pair.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {pair!r}")
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, {"True": True, "False": False}.get(value, value)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="LetterLTL0-v0", help="a single-agent env ID")
    parser.add_argument("--method", default="genz", choices=METHODS)
    parser.add_argument("--seeds", type=int, default=1, help="trainings side by side (vmap)")
    parser.add_argument("--num-envs", type=int, default=None,
                        help="envs per seed and device (default: the family's shape on this "
                             "device kind)")
    parser.add_argument("--num-steps", type=int, default=None, help="rollout steps per update")
    parser.add_argument("--minibatches", type=int, default=None, help="minibatches per epoch")
    parser.add_argument("--epochs", type=int, default=None, help="epochs per update (at most)")
    parser.add_argument("--updates", type=int, default=3, help="updates per timed call")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per part (median)")
    parser.add_argument("--map-bank", type=int, default=None,
                        help="layouts in the reset bank (default: the training's on this device "
                             "kind; 0: exact resets)")
    parser.add_argument("--env-option", type=_option, action="append", default=[],
                        metavar="KEY=VALUE", help="an override of the world, e.g. image_size=64")
    parser.add_argument("--method-option", type=_option, action="append", default=[],
                        metavar="KEY=VALUE",
                        help="a method option, e.g. image_dtype=bfloat16 (the image CNN's convolutions)")
    parser.add_argument("--learn-in-turn", choices=("on", "off"), default=None,
                        help="seeds learn one after the other, each to its own KL stop "
                             "(PPOConfig.learn_seeds_in_turn; default: the training's, on for "
                             "image worlds on an accelerator)")
    parser.add_argument("--parallel-compile", action="store_true",
                        help="compile the update and full programs side by side (each one's "
                             "compile time then shares the CPU with the other's)")
    parser.add_argument("--devices", type=int, nargs="+", default=[1], metavar="N",
                        help="profile over the first N local devices, for each N (weak "
                             "scaling: N times --num-envs envs per seed)")
    parser.add_argument("--kernels", type=int, default=0, metavar="N",
                        help="trace one rollout and one PPO step with JAX's profiler and list "
                             "their N longest kernels (0: no trace)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="append the JSON row to this file")
    parser.add_argument("--plot", default=None, metavar="PNG",
                        help="with several --devices: draw the weak scaling to this file")
    parser.add_argument("--plot-rows", default=None, metavar="JSONL",
                        help="only draw --plot from the profile rows of this file (a former "
                             "--out)")
    args = parser.parse_args(argv)
    if args.plot_rows and not args.plot:
        parser.error("--plot-rows draws to --plot PNG; give both")
    if args.plot and not args.plot_rows and len(set(args.devices)) < 2:
        parser.error("--plot draws weak scaling: give several device counts (--devices 1 2) or "
                     "--plot-rows JSONL")
    sizes = [v for v in (args.seeds, args.num_envs, args.num_steps, args.minibatches, args.epochs,
                         args.updates, args.repeats, *args.devices) if v is not None]
    if min(sizes) < 1 or (args.map_bank or 0) < 0:
        parser.error("sizes must be positive (--map-bank >= 0)")
    if max(args.devices) > jax.local_device_count():
        parser.error(f"--devices {max(args.devices)}: this process has "
                     f"{jax.local_device_count()} local device(s) ({jax.devices()[0].platform})")
    args.env_option, args.method_option = dict(args.env_option), dict(args.method_option)
    return args


def efficiencies(rates: dict[int, float]) -> dict[int, float]:
    """Weak-scaling efficiency per device count: its rate over the first count's rate scaled by
    the device ratio (1.0: perfect)."""
    first = min(rates)
    return {n: rate / (rates[first] * n / first) for n, rate in rates.items()}


def plot_scaling(rows: list[dict[str, Any]], path: str) -> None:
    """Weak scaling from profile rows (those of several device counts, per env and method): the
    training rate against the device count beside the ideal line, and each count's seconds per
    update split into rollout and PPO update, which shows what limits it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs_by_env: dict[str, dict[int, dict[str, Any]]] = collections.defaultdict(dict)
    for r in rows:
        if "rollout_s" in r and "devices" in r:
            runs_by_env[f"{r['env']} {r['method']}"][r["devices"]] = r
    if not runs_by_env:
        raise ValueError("no profile rows to plot (rows with 'rollout_s' and 'devices')")
    fig, (ax_rate, ax_split) = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / len(runs_by_env)
    for i, (name, by_count) in enumerate(sorted(runs_by_env.items())):
        counts = sorted(by_count)
        rates = [by_count[n]["full_steps_per_s"] / 1e6 for n in counts]
        scaling = efficiencies(dict(zip(counts, rates)))
        line, = ax_rate.plot(counts, rates, "o-", label=name)
        ax_rate.plot(counts, [rates[0] * n / counts[0] for n in counts], ":", color=line.get_color())
        for n, rate in zip(counts, rates):
            ax_rate.annotate(f"{scaling[n]:.2f}", (n, rate), textcoords="offset points",
                             xytext=(4, -12), fontsize=8)
        x = [j + (i - (len(runs_by_env) - 1) / 2) * width for j in range(len(counts))]
        rollout = [by_count[n]["rollout_s"] for n in counts]
        update = [by_count[n]["full_s"] - by_count[n]["rollout_s"] for n in counts]
        ax_split.bar(x, rollout, width, color=line.get_color(), label=f"{name}: rollout")
        ax_split.bar(x, update, width, bottom=rollout, color=line.get_color(), alpha=0.45,
                     label=f"{name}: PPO update")
        ax_split.set_xticks(range(len(counts)), [str(n) for n in counts])
    ax_rate.set_xticks(sorted({n for by_count in runs_by_env.values() for n in by_count}))
    ax_rate.set(xlabel="devices (env batch per device fixed)", ylabel="M env-steps/s",
                title="rate (dotted: ideal; labels: efficiency)")
    ax_split.set(xlabel="devices", ylabel="s per update",
                 title="full update step: rollout + the rest")
    for ax in (ax_rate, ax_split):
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = parse_args()
    if args.plot_rows:
        with open(args.plot_rows) as f:
            plot_scaling([json.loads(line) for line in f if line.strip()], args.plot)
        print(f"wrote {args.plot}")
        return
    rows = []
    for num_devices in args.devices:
        result = profile(args, num_devices)
        rows.append(result)
        print(table(result), flush=True)
        on = f", {num_devices} devices" if len(args.devices) > 1 or num_devices > 1 else ""
        figure = f"Training update split, {args.env} {args.method}, {args.seeds} seed(s){on}"
        value = (f"rollout {result['rollout_s']:.4f} s + update {result['update_s']:.4f} s "
                 f"(full step {result['full_s']:.4f} s) per update, "
                 f"{result['full_steps_per_s']:,.0f} env-steps/s")
        harness.emit(harness.row(figure, value, args.seeds * result["num_envs"], **result),
                     args.out)
    rates = {r["devices"]: r["full_steps_per_s"] for r in rows}
    if len(rates) > 1:
        scaling = efficiencies(rates)
        print("devices  env-steps/s  efficiency")
        for n, rate in rates.items():
            print(f"{n:7}  {rate:11,.0f}  {scaling[n]:10.2f}")
        value = ", ".join(f"{n}: {rate:,.0f} env-steps/s (efficiency {scaling[n]:.2f})"
                          for n, rate in rates.items())
        harness.emit(harness.row(f"Training weak scaling, {args.env} {args.method}, "
                                 f"{args.seeds} seed(s)", value, None, devices=max(rates),
                                 rates=rates, efficiency=scaling), args.out)
        if args.plot:
            plot_scaling(rows, args.plot)
            print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
