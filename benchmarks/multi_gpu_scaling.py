"""Scaling over the GPUs of one host: GenZ-LTL training and suite evaluation on 1, 2, 4, ... devices.

    python benchmarks/multi_gpu_scaling.py --out /tmp/scaling          # every local GPU
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/multi_gpu_scaling.py \
        --envs LetterLTL0-v0 --per-device-envs 8 --num-steps 8 --updates 1 --seeds 2 \
        --episodes 2 --suites letter/finite/ind --out /tmp/scaling       # a CPU smoke test

Training: the whole PPO loop of GenZ-LTL (the reproduction's per-update shape, `--seeds` runs
side by side as `train_baselines.py` trains them, 10 epochs without the KL stop so every update
does the same work), the env batch sharded over the first n devices. Weak scaling keeps
`--per-device-envs` per device; strong scaling keeps the largest count's global batch. The figure
is env-steps/s over all seeds, the median of `--repeats` chunks of `--updates` updates after a
compiling one; the wall-clock of seeds x 15M steps is compile + steps / that rate.

Evaluation: `experiment.evaluate` of every suite of the world (seeds x `--episodes`), episodes
sharded over the first n devices, with the trained seed-1 parameters of
the results store's `<world>/genz` cell (`store.params_path`) for every seed. Wall-clock of the compiled program, and with compile.

Writes `<out>/scaling.json` after every measurement and `<out>/scaling.png` (efficiency).
"""

from __future__ import annotations

import argparse
import json
import time
from importlib.metadata import version
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from specrl_jax.baselines import experiment, runs
from specrl_jax.baselines.ppo import env_mesh, make_train
from specrl_jax.benchmark import store

ROOT = Path(__file__).resolve().parents[1]
PER_DEVICE_ENVS = {"zone": 512, "letter": 256}  # the reproduction's batch on one accelerator


def device_counts(available: int) -> list[int]:
    """1, 2, 4, ... up to `available`, and `available` itself."""
    counts = [1 << i for i in range(available.bit_length()) if 1 << i <= available]
    return counts if counts[-1] == available else counts + [available]


def train_rate(env_id: str, num_envs: int, num_steps: int, devices: list, seeds: int,
               updates: int, repeats: int) -> dict[str, float]:
    """Env-steps/s (all seeds) of GenZ-LTL's PPO updates with the env batch over `devices`."""
    overrides = experiment.default_overrides(devices[0].platform, None, experiment.family(env_id))
    overrides.update(num_envs=num_envs, num_steps=num_steps, update_epochs=10, target_kl=None,
                     total_timesteps=num_envs * num_steps * updates * (repeats + 1))
    _, _, method, config = experiment.build("genz", env_id, overrides, 4096, jax.random.key(0))
    trainer = make_train(config, method, env_mesh(devices))
    init = jax.jit(trainer.init)
    runner = jax.tree.map(lambda *xs: jnp.stack(xs),
                          *[init(k) for k in jax.random.split(jax.random.key(1), seeds)])
    chunk = jax.jit(runs.seed_batched(trainer, seeds), static_argnums=1, donate_argnums=0)
    start = time.perf_counter()
    runner, _ = jax.block_until_ready(chunk(runner, updates, jnp.int32(updates)))
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        runner, _ = jax.block_until_ready(chunk(runner, updates, jnp.int32(updates)))
        times.append(time.perf_counter() - start)
    rate = updates * config.batch_size * seeds / sorted(times)[len(times) // 2]
    return {"env_steps_per_s": rate, "compile_s": max(first - min(times), 0.0),
            "wall_s_15M_every_seed": max(first - min(times), 0.0) + 15e6 * seeds / rate}


def eval_time(env_id: str, devices: list, seeds: int, episodes: int,
              suites: list[str]) -> dict[str, float]:
    """Seconds to evaluate `suites` (seeds x episodes) with the episodes over `devices`."""
    one = experiment.load_params("genz", env_id, store.params_path(f"{env_id}/genz"), 1)
    params = jax.tree.map(lambda x: jnp.repeat(x, seeds, axis=0), one)
    lines: list[str] = []
    start = time.perf_counter()
    experiment.evaluate("genz", env_id, params, suites, episodes, log=lines.append, devices=devices)
    total = time.perf_counter() - start
    compile_s = sum(float(line.split(" in ")[-1].rstrip("s")) for line in lines
                    if line.startswith("compiled the evaluator"))
    run_s = sum(float(line.split(" in ")[-1].rstrip("s")) for line in lines
                if line.startswith("evaluated"))
    return {"eval_run_s": run_s, "compile_s": compile_s, "total_s": total}


def plot(record: dict[str, Any], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for row_kind, style in (("weak", "-o"), ("strong", "--s")):
        for env_id in record["envs"]:
            rows = [r for r in record["train"] if r["env"] == env_id and r["scaling"] == row_kind]
            if not rows:
                continue
            base = next(r for r in rows if r["devices"] == 1)
            per_device = base["env_steps_per_s"] / (base["num_envs"] if row_kind == "weak" else 1)
            eff = [r["env_steps_per_s"] / (per_device * (r["num_envs"] if row_kind == "weak" else r["devices"]))
                   for r in rows]
            ax.plot([r["devices"] for r in rows], eff, style, label=f"{env_id} {row_kind}")
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.set_xlabel("GPUs")
    ax.set_ylabel("scaling efficiency")
    ax.set_title(f"GenZ-LTL training, {record['device']}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["PointLTL0-v0", "LetterLTL0-v0"])
    parser.add_argument("--per-device-envs", type=int, default=None,
                        help="default: the reproduction's batch (Zone 512, Letter 256)")
    parser.add_argument("--num-steps", type=int, default=128)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--updates", type=int, default=5, help="updates per timed chunk")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--suites", nargs="*", default=None, help="default: every suite of the world")
    parser.add_argument("--skip", nargs="*", default=(), choices=("train", "eval"))
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    local = jax.local_devices()
    counts = device_counts(len(local))
    record: dict[str, Any] = {
        "device": local[0].device_kind, "local_devices": len(local), "counts": counts,
        "envs": args.envs, "seeds": args.seeds, "num_steps": args.num_steps,
        "versions": {n: version(n) for n in ("jax", "jaxlib", "flax", "mujoco-mjx")},
        "date": time.strftime("%Y-%m-%d"), "train": [], "eval": []}

    def save(row: dict[str, Any], kind: str) -> None:
        record[kind].append(row)
        print(json.dumps(row), flush=True)
        (out / "scaling.json").write_text(json.dumps(record, indent=1))

    for env_id in args.envs:
        per_device = args.per_device_envs or PER_DEVICE_ENVS[experiment.family(env_id)]
        if "train" not in args.skip:
            for scaling in ("weak", "strong"):
                for n in counts:
                    if scaling == "strong" and n == counts[-1]:
                        continue  # the same shape as the weak run on every device
                    num_envs = per_device * (n if scaling == "weak" else counts[-1])
                    rate = train_rate(env_id, num_envs, args.num_steps, local[:n], args.seeds,
                                      args.updates, args.repeats)
                    save({"env": env_id, "scaling": scaling, "devices": n, "num_envs": num_envs,
                          **rate}, "train")
        if "eval" not in args.skip:
            suites = args.suites or list(experiment.suites_for(env_id))
            for n in counts:
                save({"env": env_id, "devices": n, "suites": suites, "seeds": args.seeds,
                      "episodes": args.episodes,
                      **eval_time(env_id, local[:n], args.seeds, args.episodes, suites)}, "eval")
    # the strong run on every device is the weak one
    record["train"] += [{**r, "scaling": "strong"} for r in record["train"]
                        if r["scaling"] == "weak" and r["devices"] == counts[-1]]
    (out / "scaling.json").write_text(json.dumps(record, indent=1))
    if record["train"]:
        plot(record, out / "scaling.png")


if __name__ == "__main__":
    main()
