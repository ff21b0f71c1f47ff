"""Zone robots: MJX against MuJoCo C on our models, and physics-only MJX throughput.

Fidelity: from the env's reset, `--steps` env steps (10 substeps + forward) of random actions
through `ZoneEnv.step_env` against MuJoCo C on the same model; prints the max deviation of the
agent body position, free-running and one-step (C restarted from MJX's state at each step), and
C's own spread: the largest departure from C of 4 copies of C whose qpos and qvel are changed by
one float32 rounding step (a random +-2^-24 relative) after every env step. `--x64` runs MJX in
float64 (separates float32 rounding, which chaotic dynamics amplify, from modelling
differences).

Throughput: 10 physics steps + a forward pass per env step (`Physics.step`), batched, no LiDAR,
labels or resets: what the physics alone allows. `--physics warp` measures MuJoCo Warp through MJX
(needs warp-lang). `--mjx-frame` gives MJX-JAX MJX 3.17's own capsule-plane contact frame instead
of MuJoCo C's (the Ant before `contact_frame.py`; A/B only). `--set KEY=VALUE ...` overrides
other `Solver` fields (e.g. `max_contacts=4`). Results are appended to
docs/results.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import shlex
import sys
import time

import jax

if "--x64" in sys.argv:
    jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import jaxlib
import mujoco
import numpy as np

from specrl_jax.envs.zone import make_zone
from specrl_jax.envs.zone.config import DEFAULT_SOLVERS, level_config
from specrl_jax.envs.zone.models import Solver


#: Solver field overrides from `--set`, applied on top of the robot's default or `--solver`.
OVERRIDES: dict = {}


def zone_env(robot: str, solver: Solver | None, physics: str, mjx_frame: bool = False):
    """(env, params) of the robot's level-0 world; `mjx_frame`: MJX's own capsule frame."""
    if OVERRIDES:
        solver = dataclasses.replace(solver or DEFAULT_SOLVERS[robot], **OVERRIDES)
    env, params = make_zone(level_config(robot, 0, solver=solver, physics=physics))
    if mjx_frame:
        env.physics.c_contact_frame = False
    return env, params


def fidelity(
    robot: str, steps: int, seeds: int, solver: Solver | None, physics: str, settle: int = 0,
    mjx_frame: bool = False, members: int = 4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float[seeds, steps] three times, max |MJX - C| of the agent body position (metres) per
    step: free-running (C and MJX each from their own previous state), one-step (C restarted
    from MJX's state before each step: the per-step model error, free of the amplification
    that the Car's own dynamics show at some contact events), and C's own spread (max |C' - C|
    over `members` copies C' of C perturbed by float32 rounding-sized steps after every env
    step). With `settle`, MuJoCo C first runs that many substeps at zero control and both
    continue from there."""
    env, params = zone_env(robot, solver, physics, mjx_frame)
    step = jax.jit(env.step_env)
    reset = jax.jit(env.reset)
    out, local, spread = [], [], []
    one = mujoco.MjData(env.mj_model)
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        _, state = reset(jax.random.key(seed), params)
        actions = rng.uniform(-1, 1, (steps, env.robot.action_dim)).astype(np.float32)
        data = mujoco.MjData(env.mj_model)
        data.qpos[:] = np.asarray(state.start_qpos, np.float64)
        if settle:
            for _ in range(settle):
                mujoco.mj_step(env.mj_model, data)
            dtype = state.physics.qpos.dtype
            start = jax.jit(env.physics.init)(jnp.asarray(data.qpos, dtype))
            state = state.replace(
                physics=start.replace(
                    qvel=jnp.asarray(data.qvel, dtype),
                    qacc_warmstart=jnp.asarray(data.qacc_warmstart, dtype),
                )
            )
        perturbed = [mujoco.MjData(env.mj_model) for _ in range(members)]
        for p in perturbed:
            p.qpos[:], p.qvel[:] = data.qpos, data.qvel
        rng_perturb = np.random.default_rng(10_000 + seed)
        deviation, one_step, own = [], [], []
        for a in actions:
            start = state.physics
            one.qpos[:], one.qvel[:] = np.asarray(start.qpos), np.asarray(start.qvel)
            one.qacc_warmstart[:] = np.asarray(start.qacc_warmstart)
            _, state, *_ = step(jax.random.key(0), state, jnp.asarray(a), params)
            position = np.asarray(state.physics.agent_pos)
            for d in (data, one, *perturbed):
                d.ctrl[:] = a
                for _ in range(10):
                    mujoco.mj_step(env.mj_model, d)
                mujoco.mj_forward(env.mj_model, d)
            for p in perturbed:
                for field in (p.qpos, p.qvel):
                    field *= 1 + rng_perturb.choice([-1.0, 1.0], field.shape) * 2.0**-24
            deviation.append(np.abs(position - data.xpos[1]).max())
            one_step.append(np.abs(position - one.xpos[1]).max())
            own.append(max(np.abs(p.xpos[1] - data.xpos[1]).max() for p in perturbed))
        out.append(deviation)
        local.append(one_step)
        spread.append(own)
    return np.array(out), np.array(local), np.array(spread)


def physics_throughput(
    robot: str, batch: int, steps: int, solver: Solver | None, physics: str,
    mjx_frame: bool = False,
) -> tuple[float, float]:
    """(env-steps/s, compile seconds) of the batched physics alone."""
    env, params = zone_env(robot, solver, physics, mjx_frame)
    _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(
        jax.random.split(jax.random.key(0), batch), params
    )

    def body(carry, _):
        key, data = carry
        key, key_action = jax.random.split(key)
        ctrl = jax.random.uniform(key_action, (batch, env.robot.action_dim), minval=-1, maxval=1)
        return (key, jax.vmap(env.physics.step)(data, ctrl)), None

    run = jax.jit(lambda key, data: jax.lax.scan(body, (key, data), None, steps)[0][1])
    start = time.perf_counter()
    compiled = run.lower(jax.random.key(1), state.physics).compile()
    compile_s = time.perf_counter() - start
    data = jax.block_until_ready(compiled(jax.random.key(1), state.physics))
    start = time.perf_counter()
    data = jax.block_until_ready(compiled(jax.random.key(2), data))
    return batch * steps / (time.perf_counter() - start), compile_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["Point", "Car", "Ant"])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--x64", action="store_true")
    parser.add_argument("--batches", nargs="*", type=int, default=[])
    parser.add_argument("--bench-steps", type=int, default=50)
    parser.add_argument(
        "--solver",
        nargs=3,
        type=int,
        metavar=("ITER", "LS_ITER", "CONDIM"),
        help="use these solver settings instead of the robot's default",
    )
    parser.add_argument("--physics", default="jax", choices=["jax", "warp"])
    parser.add_argument("--mjx-frame", action="store_true",
                        help="MJX 3.17's own capsule-plane contact frame (A/B against C's)")
    parser.add_argument(
        "--settle",
        type=int,
        default=0,
        help="fidelity from the state after this many C substeps at rest",
    )
    parser.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE",
        help="overrides of Solver fields (ints or True/False) on top of the robot's default or "
        "--solver, e.g. max_contacts=4",
    )
    parser.add_argument("--results", default="docs/results.md")
    args = parser.parse_args()
    args.set = {k: (v == "True" if v in ("True", "False") else int(v))
                for k, _, v in (pair.partition("=") for pair in args.set)}
    OVERRIDES.update(args.set)
    device = jax.devices()[0]
    lines = [
        "",
        (
            f"## Zone physics: MJX vs MuJoCo C, physics-only throughput ({device.device_kind}, "
            f"{datetime.date.today().isoformat()})"
        ),
        "",
        (
            f"Versions: jax {jax.__version__}, jaxlib {jaxlib.__version__}, mujoco {mujoco.__version__}, "
            f"MJX {'float64' if args.x64 else 'float32'}, physics {args.physics}"
            + (", MJX's own capsule contact frame" if args.mjx_frame else "")
            + f". Command: `{shlex.join(['python', *sys.argv])}`"
        ),
        "",
    ]
    solver = Solver(*args.solver) if args.solver else None
    label = (
        "default"
        if solver is None
        else (f"iterations {solver.iterations}, ls {solver.ls_iterations}, condim {solver.condim}")
    )
    if args.set:
        label += ", " + ", ".join(f"{k}={v}" for k, v in args.set.items())
    if args.steps:
        lines += [
            f"Solver: {label}."
            + (f" Start settled for {args.settle} substeps in C." if args.settle else ""),
            "",
            (
                "| robot | seeds | max deviation after 10 / 20 / last steps (m) | last step, per "
                "seed (m) | one-step, max (m) | max over steps per seed: MJX / C's own spread (m) |"
            ),
            "|---|---|---|---|---|---|",
        ]
        for robot in args.robots:
            per_seed, one_step, spread = fidelity(
                robot, args.steps, args.seeds, solver, args.physics, args.settle, args.mjx_frame
            )
            dev = per_seed.max(axis=0)
            marks = [dev[min(9, len(dev) - 1)], dev[min(19, len(dev) - 1)], dev[-1]]
            lines.append(
                f"| {robot} | {args.seeds} | "
                + " / ".join(f"{d:.2e}" for d in marks)
                + f" ({len(dev)} steps) | "
                + ", ".join(f"{d:.1e}" for d in per_seed[:, -1])
                + f" | {one_step.max():.1e} | "
                + ", ".join(
                    f"{d:.1e} / {c:.1e}" for d, c in zip(per_seed.max(1), spread.max(1))
                )
                + " |"
            )
            print(lines[-1], flush=True)
    if args.batches:
        lines += [
            "",
            "| robot | solver | batch | physics env-steps/s | compile s |",
            "|---|---|---|---|---|",
        ]
        for robot in args.robots:
            for batch in args.batches:
                rate, compile_s = physics_throughput(
                    robot, batch, args.bench_steps, solver, args.physics, args.mjx_frame
                )
                lines.append(f"| {robot} | {label} | {batch} | {rate:,.0f} | {compile_s:.1f} |")
                print(lines[-1], flush=True)
    with open(args.results, "a") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
