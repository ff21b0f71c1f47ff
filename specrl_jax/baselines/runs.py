"""Run directories: config, metrics over time (JSON lines), checkpoints with resume, a training
curve, and a progress line with env-steps/s.

Layout of `run_dir`: `config.json`, `metrics.jsonl` (one line per update), `checkpoint.msgpack`
(the whole `RunnerState`, flax serialisation), `curve.png`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any, Callable

import jax
import numpy as np
from flax import serialization

from specrl_jax.baselines.ppo.train import RunnerState, Trainer

CHECKPOINT = "checkpoint.msgpack"


def save_checkpoint(path: str | os.PathLike, runner: RunnerState) -> None:
    """Write `runner` atomically (typed PRNG keys are stored as raw key data)."""
    runner = jax.device_get(runner.replace(key=jax.random.key_data(runner.key)))
    tmp = Path(f"{path}.tmp")
    tmp.write_bytes(serialization.to_bytes(runner))
    tmp.replace(path)


def load_checkpoint(path: str | os.PathLike, template: RunnerState) -> RunnerState:
    """Read a checkpoint written by `save_checkpoint` into the structure of `template`."""
    raw = template.replace(key=jax.random.key_data(template.key))
    restored = serialization.from_bytes(jax.device_get(raw), Path(path).read_bytes())
    restored = jax.tree.map(lambda t, x: jax.device_put(np.asarray(x), t.sharding), raw, restored)
    return restored.replace(key=jax.random.wrap_key_data(restored.key))


def _scalars(metrics: dict[str, Any], i: int) -> dict[str, float]:
    return {k: float(np.asarray(v)[i]) for k, v in metrics.items()}


def train_in_run_dir(
    trainer: Trainer,
    key: jax.Array,
    run_dir: str | os.PathLike,
    chunk_updates: int = 10,
    extra_config: dict[str, Any] | None = None,
    summarise: Callable[[dict[str, float]], dict[str, float]] = lambda m: m,
    log: Callable[[str], None] = print,
    max_updates: int | None = None,
) -> RunnerState:
    """Train `trainer` in chunks of `chunk_updates`, resuming from `run_dir` when it holds a checkpoint.

    `summarise` derives extra scalars per update (e.g. rates); `max_updates` stops early (tests).
    Returns the final runner state.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg = trainer.config
    config = {"ppo": dataclasses.asdict(cfg), **(extra_config or {})}
    (run_dir / "config.json").write_text(json.dumps(config, indent=2, default=str))
    runner = jax.jit(trainer.init)(key)
    if (run_dir / CHECKPOINT).exists():
        runner = load_checkpoint(run_dir / CHECKPOINT, runner)
        log(f"resumed at update {int(runner.update)} from {run_dir / CHECKPOINT}")
    updates = jax.jit(trainer.updates, static_argnums=1, donate_argnums=0)
    total = cfg.num_updates if max_updates is None else min(cfg.num_updates, max_updates)
    start_wall = time.perf_counter()
    done_at_start = int(runner.update)
    with open(run_dir / "metrics.jsonl", "a") as out:
        while int(runner.update) < total:
            n = min(chunk_updates, total - int(runner.update))
            runner, metrics = updates(runner, n)
            metrics = jax.device_get(metrics)
            elapsed = time.perf_counter() - start_wall
            for i in range(n):
                update = int(runner.update) - n + i + 1
                row = summarise(_scalars(metrics, i))
                row.update(update=update, env_steps=update * cfg.batch_size, wall_s=elapsed)
                out.write(json.dumps(row) + "\n")
            out.flush()
            steps = (int(runner.update) - done_at_start) * cfg.batch_size
            log(
                f"update {int(runner.update)}/{total}  env steps {int(runner.update) * cfg.batch_size:,}  "
                f"{steps / elapsed:,.0f} steps/s  "
                + "  ".join(f"{k} {v:.3f}" for k, v in row.items() if k not in ("update", "env_steps", "wall_s"))
            )
            save_checkpoint(run_dir / CHECKPOINT, runner)
    plot_curve(run_dir)
    return runner


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
