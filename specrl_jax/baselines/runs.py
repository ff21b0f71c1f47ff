"""Run directories: config, metrics over time (JSON lines), checkpoints with resume, a training
curve, and a progress line with env-steps/s.

Layout of `run_dir`: `config.json`, `metrics.jsonl` (one line per update), `checkpoint.msgpack`
(the whole `RunnerState`, flax serialisation, booleans as packed bits), `curve.png`. In a job of several processes
(`hosts`), process 0 alone writes them and every process resumes from its checkpoint.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from specrl_jax.automata.tensors import pack_step_planes
from specrl_jax.baselines import hosts
from specrl_jax.baselines.compile_log import compile_logged, in_background
from specrl_jax.baselines.params_io import load_params, load_params_into, save_params
from specrl_jax.baselines.ppo.train import RunnerState, Trainer

CHECKPOINT = "checkpoint.msgpack"


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during `train_in_run_dir`: the run directory holds a checkpoint at `update` (0:
    none yet), from which the same call resumes exactly."""

    def __init__(self, run_dir: Path, update: int):
        super().__init__(f"interrupted at update {update}; run the same command to resume")
        self.run_dir, self.update = run_dir, update


def save_checkpoint(path: str | os.PathLike, runner: RunnerState) -> None:
    """Write `runner` atomically (typed PRNG keys are stored as raw key data, boolean arrays as
    packed bits: a task's reach and avoid sets over a large alphabet are most of an env's state);
    in a job of several processes call it on every process (it gathers the sharded env batch),
    process 0 writes."""
    state = hosts.host_copy(runner.replace(key=jax.random.key_data(runner.key)))
    if hosts.is_writer():
        save_params(path, jax.tree.map(
            lambda x: np.packbits(x, axis=None) if x.dtype == bool else x, state))


def _unpack_bits(template: Any, stored: Any) -> Any:
    """`stored` (a checkpoint's state dict) with the bits `save_checkpoint` packed unpacked into
    the boolean arrays of `template` (its state dict); a checkpoint of unpacked booleans is
    left as it is."""
    if isinstance(stored, dict):
        return {k: _unpack_bits(template[k], v) if isinstance(template, dict) and k in template
                else v for k, v in stored.items()}
    want, bits = np.asarray(template), np.asarray(stored)
    if want.dtype == bool and bits.dtype == np.uint8 and bits.shape == (-(-want.size // 8),):
        return np.unpackbits(bits, count=want.size).reshape(want.shape).astype(bool)
    return stored  # another shape: `load_checkpoint` names it


def _flat_moments(template: Any, stored: Any) -> Any:
    """`stored` (a checkpoint's optimizer state dict) with every per-parameter tree that
    `template` holds as one flat vector (`optax.flatten`'s Adam moments, `[..., P]`) raveled
    into it, in the order `optax.flatten` ravels the parameters (sorted keys, as jax's tree
    order): checkpoints written with the per-parameter optimizer state still resume."""
    if isinstance(stored, dict) and isinstance(template, dict):
        return {k: _flat_moments(template[k], v) if k in template else v
                for k, v in stored.items()}
    if isinstance(stored, dict) and stored and not isinstance(template, dict):
        lead = np.shape(template)[:-1]
        return np.concatenate([np.reshape(x, (*lead, -1)) for x in jax.tree.leaves(stored)], -1)
    return stored


def load_checkpoint(path: str | os.PathLike, template: RunnerState) -> RunnerState:
    """Read a checkpoint written by `save_checkpoint` into the structure of `template`.

    Raises:
        ValueError: naming the file, when it cannot be read or does not fit `template`.
    """
    raw = template.replace(key=jax.random.key_data(template.key))
    zeros = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), raw)
    try:
        stored = add_derived_spec_fields(load_params(path, what="training checkpoint"))
        stored = _unpack_bits(serialization.to_state_dict(zeros), stored)
        if isinstance(stored, dict) and "opt_state" in stored:
            stored["opt_state"] = _flat_moments(
                serialization.to_state_dict(zeros.opt_state), stored["opt_state"])
        restored = load_params_into(zeros, stored)
        for (where, want), got in zip(jax.tree_util.tree_leaves_with_path(zeros),
                                      jax.tree.leaves(restored), strict=True):
            if np.shape(got) != want.shape:
                raise ValueError(f"{jax.tree_util.keystr(where)} is stored as {np.shape(got)}, "
                                 f"this run's is {want.shape}")
    except ValueError as err:
        raise ValueError(f"checkpoint {path} cannot be read ({err}); delete it to train this "
                         "run from its start (or pass --restart), or use another --out") from err
    restored = jax.tree.map(lambda t, x: hosts.put_like(np.asarray(x), t), raw, restored)
    return restored.replace(key=jax.random.wrap_key_data(restored.key))


def add_derived_spec_fields(state: Any) -> Any:
    """A checkpoint's state dict with `step_planes` derived from `step_table` wherever a spec
    lacks it: checkpoints written before specs carried the planes still resume."""
    if not isinstance(state, dict):
        return state
    state = {name: add_derived_spec_fields(value) for name, value in state.items()}
    if "step_table" in state and "step_planes" not in state:
        state["step_planes"] = pack_step_planes(np.asarray(state["step_table"]))
    return state


def _rows(metrics: dict[str, Any], num: int, summarise: Callable) -> list[dict[str, float]]:
    """Metrics `[seeds, num]` -> one row per update: the mean over seeds of each (summarised)
    scalar, plus `success_rate_seeds` when a success rate is present."""
    out = []
    for i in range(num):
        per_seed = [
            summarise({k: float(np.asarray(v)[s, i]) for k, v in metrics.items()})
            for s in range(np.asarray(next(iter(metrics.values()))).shape[0])
        ]
        row = {k: float(np.mean([r[k] for r in per_seed])) for k in per_seed[0]}
        if "success_rate" in per_seed[0]:
            row["success_rate_seeds"] = [r["success_rate"] for r in per_seed]
        out.append(row)
    return out


def over_seeds(fn: Callable, num_seeds: int, in_axes: int | tuple[int | None, ...] = 0
               ) -> Callable:
    """`fn` over a leading seed axis of the arguments `in_axes` marks (0; None: shared by every
    seed) and of every output. One seed runs unbatched: under `vmap` the KL stop's while-loop
    predicate is batched, which selects the whole carry every epoch."""
    if num_seeds > 1:
        return jax.vmap(fn, in_axes=in_axes)

    def single(*args: Any) -> Any:
        axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
        args = [a if axis is None else jax.tree.map(lambda x: x[0], a)
                for a, axis in zip(args, axes)]
        return jax.tree.map(lambda x: x[None], fn(*args))

    return single


def seed_batched(trainer: Trainer, num_seeds: int) -> Callable:
    """`trainer.updates` over a leading seed axis of the runner state and the metrics (the
    seeds learning in turn with `PPOConfig.learn_seeds_in_turn`)."""
    if num_seeds > 1 and trainer.config.learn_seeds_in_turn:
        def in_turn(runner: RunnerState, num_updates: int, active: jax.Array | None = None) -> Any:
            runner, metrics = trainer.updates(runner, num_updates, active,
                                              step=trainer.update_seeds_in_turn)
            return runner, jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), metrics)  # [seeds, num]

        return in_turn
    return over_seeds(trainer.updates, num_seeds, in_axes=(0, None, None))


def seed_keys(key: jax.Array, num_seeds: int, first_seed: int = 1) -> jax.Array:
    """The keys of seeds `first_seed` .. `first_seed + num_seeds - 1` of a run from `key`: rows
    `first_seed - 1` on of `split(key, last)`. `split` gives a longer split the same leading rows,
    so seeds trained in parts get the keys they have in one run of them all."""
    if first_seed < 1 or num_seeds < 1:
        raise ValueError(f"seeds are numbered from 1; got {num_seeds} seeds from {first_seed}")
    if first_seed > 1 and not jax.config.jax_threefry_partitionable:
        raise ValueError("seeds from a first seed above 1 need jax_threefry_partitionable=True "
                         "(JAX's default), under which a split's leading rows do not depend on "
                         "its length")
    return jax.random.split(key, first_seed - 1 + num_seeds)[first_seed - 1:]


def init_seeds(trainer: Trainer, key: jax.Array, num_seeds: int,
               log: Callable[[str], None] | None = None, program_key: str | None = None,
               first_seed: int = 1) -> RunnerState:
    """`num_seeds` initial runner states from `key` (seeds `first_seed` on, `seed_keys`),
    stacked on a leading seed axis; `program_key` names the traced program on disk
    (`compile_logged`)."""
    keys = seed_keys(key, num_seeds, first_seed)
    # Seeds are initialised one by one: a vmapped orthogonal init (batched QR) hangs on XLA:CPU.
    init = compile_logged(trainer.init, (keys[0],), "the initial state (env reset, network init)",
                          log, program_key)
    seeds = [init(k) for k in keys]
    # one program for the whole tree: stacking leaf by leaf compiles one per leaf shape
    return jax.jit(lambda *trees: jax.tree.map(lambda *xs: jnp.stack(xs), *trees))(*seeds)


def runner_shapes(trainer: Trainer, key: jax.Array, num_seeds: int) -> RunnerState:
    """The shapes and dtypes of `init_seeds(trainer, key, num_seeds)`, without computing it."""
    one = jax.eval_shape(trainer.init, jax.random.split(key, num_seeds)[0])
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct((num_seeds, *x.shape), x.dtype), one)


def compile_updates(trainer: Trainer, runner: RunnerState, num_seeds: int, chunk_updates: int,
                    log: Callable[[str], None] | None = None, program_key: str | None = None
                    ) -> Callable:
    """The training step of `num_seeds` seeds side by side, `updates(runner, n)` running `n` of
    `chunk_updates` updates, compiled for `runner` (arrays or `runner_shapes`). One compiled
    chunk serves every chunk: a shorter chunk runs the same scan, partly idle."""
    return compile_logged(seed_batched(trainer, num_seeds), (runner, chunk_updates, jnp.int32(1)),
                          "the training step", log, program_key, static_argnums=1,
                          donate_argnums=0)


def train_chunks(trainer: Trainer, runner: RunnerState, num_seeds: int, chunk_updates: int,
                 total: int, first_chunk: int | None = None,
                 log: Callable[[str], None] | None = None, program_key: str | None = None,
                 on_compiled: Callable[[], None] | None = None,
                 compiled: Future | None = None
                 ) -> Iterator[tuple[RunnerState, dict[str, Any], int, int]]:
    """The one training driver: from `runner`'s update (seed axis first) to `total`, in chunks of
    at most `chunk_updates` updates (the first of at most `first_chunk`, e.g. 1 to report the
    update that included compilation at once). Yields `(runner, metrics [seeds, chunk_updates]
    on the host, updates in this chunk, updates done)` after each chunk, so callers log,
    checkpoint or stop; `log` hears what compiles and how long it took; `program_key` names the
    traced program on disk (`compile_logged`); `compiled`, if given, holds `compile_updates`'
    result for this runner's shapes (compiled while something else ran); `on_compiled()` runs
    once the step has compiled, before it runs (work for the host while the device trains)."""
    done = int(runner.update[0])
    if done >= total:
        return
    updates = (compiled.result() if compiled is not None else
               compile_updates(trainer, runner, num_seeds, chunk_updates, log, program_key))
    if on_compiled is not None:
        on_compiled()
    size = min(first_chunk or chunk_updates, chunk_updates)
    while done < total:
        n = min(size, total - done)
        size = chunk_updates
        runner, metrics = updates(runner, jnp.int32(n))
        done += n
        yield runner, jax.device_get(metrics), n, done


def train_in_run_dir(
    trainer: Trainer,
    key: jax.Array,
    run_dir: str | os.PathLike,
    chunk_updates: int = 10,
    num_seeds: int = 1,
    extra_config: dict[str, Any] | None = None,
    summarise: Callable[[dict[str, float]], dict[str, float]] = lambda m: m,
    log: Callable[[str], None] = print,
    max_updates: int | None = None,
    max_wall_s: float | None = None,
    restart: bool = False,
    first_chunk: int | None = None,
    program_key: str | None = None,
    on_compiled: Callable[[], None] | None = None,
    compile_step_early: bool = True,
    first_seed: int = 1,
) -> RunnerState:
    """Train `num_seeds` runs of `trainer` side by side (`vmap`) in chunks of `chunk_updates`,
    resuming from `run_dir` when it holds a checkpoint.

    `summarise` derives extra scalars per update and seed (e.g. rates); `max_updates` and
    `max_wall_s` (this session's seconds, checked after each chunk) stop early, resumable;
    `first_chunk` bounds the session's first chunk (1: the update that includes compilation is
    reported as soon as it ends); `program_key` names the traced programs on disk, so that a
    second identical run does not trace them (`compile_logged`); `on_compiled()` runs once the
    training step has compiled, before it runs (`train_chunks`); `compile_step_early` compiles
    the training step of a fresh run on one device while its initial state compiles and runs
    (False: one program at a time, for programs whose lowering is not thread-safe); the seeds
    are seeds `first_seed` on of a run (`seed_keys`: a part of a run's seeds). Ctrl-C raises
    `TrainingInterrupted` naming the checkpointed update. Rows'
    `wall_s` is training time summed over sessions (a resumed run continues the clock of the
    checkpoint's update), so rates and times to a level stay on one clock. A run directory is
    resumed only when its `config.json` equals this run's settings (else `ValueError` names the
    differing settings); `restart` discards what it holds. Returns the final runner state, with a
    leading seed axis `[num_seeds]`.

    In a job of several processes (`hosts`) every process calls it alike: process 0 writes the
    run directory and logs, every process resumes from its checkpoint, and the wall-clock
    budget is process 0's.
    """
    cfg = trainer.config
    writer = hosts.is_writer()
    config = run_config(cfg, num_seeds, extra_config)
    run_dir = check_run_dir(run_dir, config, restart)
    hosts.barrier("run directory checked")  # every process has read it before process 0 writes
    log = hosts.writer_log(log)
    if writer:
        _start_run_dir(run_dir, config, restart)
    total = cfg.num_updates if max_updates is None else min(cfg.num_updates, max_updates)
    compiled = None
    if (compile_step_early and (trainer.mesh is None or trainer.mesh.size == 1) and total > 0
            and not (run_dir / CHECKPOINT).exists()):
        # a fresh run on one device: the training step compiles while the initial state does
        shapes = runner_shapes(trainer, key, num_seeds)
        compiled = in_background(compile_updates, trainer, shapes, num_seeds, chunk_updates, log,
                                 program_key)
    runner = init_seeds(trainer, key, num_seeds, log, program_key, first_seed)
    hosts.barrier("run directory ready")
    wall_before = 0.0
    if (run_dir / CHECKPOINT).exists():
        runner = load_checkpoint(run_dir / CHECKPOINT, runner)
        wall_before = _wall_at(run_dir, int(runner.update[0]))
        log(f"resumed at update {int(runner.update[0])} from {run_dir / CHECKPOINT} "
            f"after {wall_before:.1f}s of training")
    start_wall = time.perf_counter()
    done_at_start = checkpointed = int(runner.update[0])
    if writer:
        _drop_rows_after(run_dir, done_at_start)  # rows written before an interrupted checkpoint
    try:
        with open(run_dir / "metrics.jsonl", "a") if writer else contextlib.nullcontext() as out:
            chunks = train_chunks(trainer, runner, num_seeds, chunk_updates, total, first_chunk,
                                  log, program_key, on_compiled, compiled)
            rate_from = None  # after the first chunk: rates since it ended, without compilation
            for runner, metrics, n, done in chunks:
                elapsed = time.perf_counter() - start_wall
                if writer:
                    _log_chunk(out, metrics, n, done, rate_from or (done_at_start, 0.0),
                               rate_from is None, total, cfg, num_seeds, wall_before, elapsed,
                               summarise, log)
                rate_from = rate_from or (done, elapsed)
                save_checkpoint(run_dir / CHECKPOINT, runner)
                checkpointed = done
                if max_wall_s is not None and hosts.from_writer(np.bool_(elapsed > max_wall_s)):
                    log(f"stopping at update {done}: wall-clock budget of {max_wall_s:.0f}s spent")
                    break
    except KeyboardInterrupt as err:
        raise TrainingInterrupted(run_dir, checkpointed) from err
    if writer:
        plot_curve(run_dir)
    hosts.barrier("run directory written")  # every process reads what process 0 wrote
    return runner


def _start_run_dir(run_dir: Path, config: dict[str, Any], restart: bool) -> None:
    """Write `config.json` in `run_dir`, first discarding the run it holds if `restart`."""
    if restart:
        for name in (CHECKPOINT, "metrics.jsonl", "config.json", "curve.png"):
            (run_dir / name).unlink(missing_ok=True)
    try:
        (run_dir / "config.json").write_text(json.dumps(config, indent=2))
    except OSError as err:
        raise ValueError(f"cannot write to the run directory {run_dir}: {err.strerror}") from err


def _log_chunk(out: Any, metrics: dict[str, Any], n: int, done: int,
               rate_from: tuple[int, float], first: bool, total: int, cfg: Any, num_seeds: int,
               wall_before: float, elapsed: float, summarise: Callable,
               log: Callable[[str], None]) -> None:
    """Append a chunk's rows to `metrics.jsonl` and log a progress line (the rate since
    `rate_from`'s (update, elapsed s); the session's `first` chunk marked as compiling)."""
    rows = _rows(metrics, n, summarise)
    for i, row in enumerate(rows):
        update = done - n + i + 1
        row.update(update=update, env_steps=update * cfg.batch_size, wall_s=wall_before + elapsed)
        out.write(json.dumps(row) + "\n")
    out.flush()
    rate = (done - rate_from[0]) * cfg.batch_size * num_seeds / max(elapsed - rate_from[1], 1e-9)
    shown = {k: v for k, v in rows[-1].items() if isinstance(v, float) and k not in ("env_steps", "wall_s")}
    note = f"  ({elapsed:.0f}s, compilation included)" if first else ""
    log(
        f"update {done}/{total}  env steps {done * cfg.batch_size:,} x {num_seeds} seeds  "
        f"{rate:,.0f} steps/s  " + "  ".join(f"{k} {v:.3g}" for k, v in shown.items()) + note
    )


def run_config(cfg: Any, num_seeds: int, extra_config: dict[str, Any] | None = None
               ) -> dict[str, Any]:
    """What a run directory's `config.json` holds for these settings (as JSON reads it back)."""
    return json.loads(json.dumps(
        {"ppo": dataclasses.asdict(cfg), "num_seeds": num_seeds, **(extra_config or {})},
        default=str))


def check_run_dir(run_dir: str | os.PathLike, config: dict[str, Any], restart: bool = False
                  ) -> Path:
    """Create `run_dir` and check, before any expensive step, that it is writable and (unless
    `restart`) fresh or holding a run of exactly `config`'s settings (`check_resumable`);
    writes nothing in it. Returns it as a `Path`. Processes other than process 0 of a job of
    several only read it.

    Raises:
        ValueError: saying which, and what to do.
    """
    run_dir = Path(run_dir)
    if not hosts.is_writer():
        if not restart:
            check_resumable(run_dir, config)
        return run_dir
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"cannot create the run directory {run_dir}: {err.strerror}") from err
    if not os.access(run_dir, os.W_OK | os.X_OK):
        raise ValueError(f"cannot write to the run directory {run_dir}: Permission denied")
    if not restart:
        check_resumable(run_dir, config)
    return run_dir


def _drop_rows_after(run_dir: Path, update: int) -> None:
    """Keep `metrics.jsonl`'s rows up to `update` (the checkpoint's): an interrupted session may
    have written rows of a chunk whose checkpoint it did not."""
    path = run_dir / "metrics.jsonl"
    if not path.exists():
        return
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    kept = [line for line in lines if _row_update(line) <= update]
    if len(kept) < len(lines):
        path.write_text("".join(line + "\n" for line in kept))


def _row_update(line: str) -> float:
    """A metrics line's update; infinity for a line cut short by an interruption."""
    try:
        return json.loads(line)["update"]
    except (ValueError, KeyError, TypeError):
        return float("inf")


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(tree, dict):
        return {prefix: tree}
    out = {}
    for key, value in tree.items():
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def check_resumable(run_dir: Path, config: dict[str, Any]) -> None:
    """Raise unless `run_dir` is fresh or holds a run of exactly these settings."""
    stored_path = run_dir / "config.json"
    has_run = (run_dir / CHECKPOINT).exists() or (run_dir / "metrics.jsonl").exists()
    if not has_run:
        return
    try:
        stored = json.loads(stored_path.read_text()) if stored_path.exists() else {}
    except (OSError, ValueError) as err:
        raise ValueError(f"{stored_path} cannot be read ({err}); pass --restart to discard the "
                         f"run in {run_dir}, or use another --out") from err
    old, new = _flat(stored), _flat(config)
    differing = sorted(k for k in old.keys() | new.keys() if old.get(k) != new.get(k))
    if differing:
        shown = ", ".join(f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in differing[:6])
        more = f" and {len(differing) - 6} more" if len(differing) > 6 else ""
        raise ValueError(
            f"{run_dir} holds a run with other settings ({shown}{more}); resume it with its own "
            "settings, pick a new --out, or pass --restart to discard it"
        )


def _wall_at(run_dir: Path, update: int) -> float:
    """Training seconds of earlier sessions up to `update` (the checkpoint's): `wall_s` of the last
    row written for it in `metrics.jsonl`; 0 without one."""
    if not (run_dir / "metrics.jsonl").exists():
        return 0.0
    return next((r["wall_s"] for r in reversed(read_metrics(run_dir)) if r["update"] == update), 0.0)


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, float]]:
    path = Path(run_dir) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot_curve(run_dir: str | os.PathLike, keys: tuple[str, ...] = ("success_rate", "violation_rate")) -> None:
    """`curve.png`: the named metrics against env steps (those present in `metrics.jsonl`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_metrics(run_dir)
    present = [k for k in keys if rows and k in rows[0]]
    if not present:
        return
    fig, ax = plt.subplots(figsize=(6, 3.5))
    steps = [r["env_steps"] for r in rows]
    for k in present:
        ax.plot(steps, [r[k] for r in rows], label=k)
    ax.set_xlabel("env steps")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(Path(run_dir) / "curve.png", dpi=100)
    plt.close(fig)
