"""Moving zones: our weld trajectory against the original's weld in MuJoCo C, and its cost.

Fidelity (`--fidelity`, CPU is enough): for `--layouts` hand-made layouts per robot (all 8 zones
moving, random centres, directions and phases), the largest distance between
`ZoneEnv.zone_positions` and the original's zone bodies in MuJoCo C
(`envs/zone/weld_reference.py`) over steps 0-100 and 101-`--steps`, for `zone_motion="weld"`
(default) and the kinematic "circle".

Throughput (`--throughput`): env-steps/s of `--envs` with both zone motions, auto-resetting from a
layout bank (the setting where zone motion weighs most: no rejection sampler), measured as
`env_throughput.py` does (scan of random-action steps, every output folded into a checksum); the
two motions are timed in alternation, `--repeats` rounds, best and median per motion.

Results are appended to docs/results.md (or --results).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import shlex
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import jaxlib
import mujoco
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from env_throughput import make_rollout  # noqa: E402

import specrl_jax  # noqa: E402
from specrl_jax.envs.wrappers import batch  # noqa: E402
from specrl_jax.envs.zone.env import ZoneState  # noqa: E402
from specrl_jax.envs.zone.weld_reference import original_zone_trajectory  # noqa: E402


def fidelity(robot: str, motion: str, seed: int, steps: int) -> tuple[float, float]:
    """Max |ours - C| (metres) of the zone centres over env steps 0-100 and 101-`steps`."""
    env, _ = specrl_jax.make(f"{robot}LTL2-v0", zone_motion=motion)
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-1.8, 1.8, (8, 2))
    direction, phase = rng.choice([-1.0, 1.0], 8), rng.uniform(0, 2 * np.pi, 8)
    as32 = lambda a: jnp.asarray(a, jnp.float32)
    state = ZoneState(None, None, as32(centre), as32(direction), as32(phase), jnp.int32(0))
    at = jax.jit(jax.vmap(lambda t: env.zone_positions(state.replace(time=t))))
    ours = np.asarray(at(jnp.arange(steps + 1, dtype=jnp.int32)))
    c_xyz = original_zone_trajectory(
        robot, centre, direction, phase, steps, zone_yaw=rng.uniform(0, 2 * np.pi, 8)
    )
    error = np.linalg.norm(ours - c_xyz[..., :2], axis=-1)
    return float(error[:101].max()), float(error[101:].max())


def throughput(
    env_ids: list[str], batch_size: int, steps: int, repeats: int, bank: int
) -> list[dict]:
    runs = []
    for env_id in env_ids:
        for motion in ("weld", "circle"):
            env, params = specrl_jax.make(env_id, zone_motion=motion)
            key_bank, key_reset, key_run = jax.random.split(jax.random.key(0), 3)
            params = jax.block_until_ready(env.with_map_bank(key_bank, params, bank))
            batched = batch(env, batch_size)
            _, state = jax.jit(batched.reset)(key_reset, params)
            rollout = make_rollout(batched, params, steps)
            start = time.perf_counter()
            compiled = rollout.lower(key_run, state).compile()
            compile_s = time.perf_counter() - start
            state, _ = jax.block_until_ready(compiled(key_run, state))  # warm-up
            runs.append({
                "env": env_id, "motion": motion, "run": compiled, "state": state,
                "key": key_run, "times": [], "compile_s": compile_s,
            })
    for repeat in range(repeats):  # alternate the motions, so drifts hit both alike
        for run in runs:
            start = time.perf_counter()
            run["state"], _ = jax.block_until_ready(
                run["run"](jax.random.fold_in(run["key"], repeat), run["state"])
            )
            run["times"].append(time.perf_counter() - start)
    for run in runs:
        run["best"] = batch_size * steps / min(run["times"])
        run["median"] = batch_size * steps / statistics.median(run["times"])
        print(
            f"{run['env']} {run['motion']}: best {run['best']:,.0f}, median "
            f"{run['median']:,.0f} env-steps/s, compile {run['compile_s']:.1f} s", flush=True,
        )
    return runs


def header(title: str) -> str:
    device = jax.devices()[0]
    return (
        f"\n## {title}: {device.platform}: {device.device_kind}, "
        f"{datetime.date.today().isoformat()}\n\n"
        f"Versions: jax {jax.__version__}, jaxlib {jaxlib.__version__}, "
        f"mujoco {mujoco.__version__}, "
        f"specrl_jax {specrl_jax.__version__}, Python {platform.python_version()}. "
        f"Command: `{shlex.join(['python', *sys.argv])}`\n\n"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fidelity", action="store_true")
    parser.add_argument("--throughput", action="store_true")
    parser.add_argument("--layouts", type=int, default=3)
    parser.add_argument("--steps", type=int, default=300, help="env steps of the C comparison")
    parser.add_argument("--envs", nargs="+", default=["PointLTL1-v0", "PointLTL2-v0"])
    parser.add_argument("--batch", type=int, default=262144)
    parser.add_argument("--call-steps", type=int, default=20, help="env steps per compiled call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--bank-size", type=int, default=65536)
    parser.add_argument("--results", default="docs/results.md")
    args = parser.parse_args()
    if args.fidelity:
        text = header("Zone: moving zones against the original's weld in MuJoCo C")
        text += "| robot | zone motion | layouts | max error, steps 0-100 (m) | "
        text += f"max error, steps 101-{args.steps} (m) |\n|---|---|---|---|---|\n"
        for robot in ("Point", "Car", "Ant"):
            for motion in ("weld", "circle"):
                errors = np.array(
                    [fidelity(robot, motion, s, args.steps) for s in range(args.layouts)]
                )
                worst = errors.max(axis=0)
                row = f"| {robot} | {motion} | {args.layouts} | {worst[0]:.2e} | {worst[1]:.2e} |"
                print(row, flush=True)
                text += row + "\n"
        append(args.results, text)
    if args.throughput:
        runs = throughput(args.envs, args.batch, args.call_steps, args.repeats, args.bank_size)
        text = header("Zone: moving-zone motion, weld against circle, bank resets")
        text += "| env | zone motion | batch | steps/call | env-steps/s (best) | "
        text += "env-steps/s (median) | compile s |\n"
        text += "|---|---|---|---|---|---|---|\n"
        for r in runs:
            text += (
                f"| {r['env']} | {r['motion']} | {args.batch:,} | {args.call_steps} | "
                f"{r['best']:,.0f} | {r['median']:,.0f} | {r['compile_s']:.1f} |\n"
            )
        append(args.results, text)


def append(path: str, text: str) -> None:
    with open(path, "a") as f:
        f.write(text)


if __name__ == "__main__":
    main()
