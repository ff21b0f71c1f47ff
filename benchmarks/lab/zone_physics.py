"""Zone robots: MJX (or MuJoCo Warp) against MuJoCo C on our models.

Fidelity: from the env's reset, `--steps` env steps (10 substeps + forward) of random actions
through `ZoneEnv.step_env` against MuJoCo C on the same model; prints the max deviation of the
agent body position, free-running and one-step (C restarted from MJX's state at each step), and
C's own spread: the largest departure from C of 4 copies of C whose qpos and qvel are changed by
one float32 rounding step (a random +-2^-24 relative) after every env step. `--x64` runs MJX in
float64 (separates float32 rounding, which chaotic dynamics amplify, from modelling
differences).

`--physics warp` runs MuJoCo Warp through MJX (needs warp-lang). `--mjx-frame` gives MJX-JAX
MJX 3.17's own capsule-plane contact frame instead of MuJoCo C's (A/B only). `--set KEY=VALUE
...` overrides `Solver` fields (e.g. `max_contacts=4`). `--matmul-precision highest` runs every
float32 matrix product in full float32 (JAX's default lets a GPU use TF32 on its tensor cores; a
CPU is unaffected). Prints one JSON row per robot
(`benchmarks/harness.py`), appended to `--out` if given.

    python benchmarks/lab/zone_physics.py --robots Car --steps 50 --seeds 8
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import jax

if "--x64" in sys.argv:
    jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import mujoco
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import harness

from specrl_jax.envs.zone import make_zone
from specrl_jax.envs.zone.config import DEFAULT_SOLVERS, level_config
from specrl_jax.envs.zone.models import Solver

#: Solver field overrides from `--set`, applied on top of the robot's default.
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["Point", "Car", "Ant"])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--x64", action="store_true", help="MJX in float64")
    parser.add_argument("--physics", default="jax", choices=["jax", "warp"])
    parser.add_argument("--mjx-frame", action="store_true",
                        help="MJX 3.17's own capsule-plane contact frame (A/B against C's)")
    parser.add_argument("--settle", type=int, default=0,
                        help="start from the state after this many C substeps at rest")
    parser.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE",
        help="overrides of the robot's default Solver fields (ints or True/False), "
        "e.g. max_contacts=4",
    )
    parser.add_argument("--matmul-precision", default=None, choices=["default", "high", "highest"],
                        help="jax_default_matmul_precision for this process (default: JAX's)")
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    if args.matmul_precision:
        jax.config.update("jax_default_matmul_precision", args.matmul_precision)
    OVERRIDES.update({k: (v == "True" if v in ("True", "False") else int(v))
                      for k, _, v in (pair.partition("=") for pair in args.set)})
    settings = [args.physics, "float64" if args.x64 else "float32"]
    settings += ["MJX's own capsule frame"] * args.mjx_frame
    settings += [f"{k}={v}" for k, v in OVERRIDES.items()]
    settings += [f"settled {args.settle} substeps in C"] * bool(args.settle)
    settings += [f"matmul precision {args.matmul_precision}"] * bool(args.matmul_precision)
    for robot in args.robots:
        free, one_step, spread = fidelity(robot, args.steps, args.seeds, None, args.physics,
                                          args.settle, args.mjx_frame)
        worst = free.max(axis=0)
        value = (f"free-running {worst[-1]:.2e} m after {args.steps} steps, one-step "
                 f"{one_step.max():.1e} m, C's own spread {spread.max():.1e} m")
        harness.emit(harness.row(
            f"{robot}LTL0-v0, MJX ({', '.join(settings)}) vs MuJoCo C, max body deviation, "
            f"{args.seeds} seeds x {args.steps} random-action steps", value, None,
            free_running_per_step=[float(d) for d in worst],
            one_step_max=float(one_step.max()),
            free_running_per_seed=[float(d) for d in free.max(axis=1)],
            c_spread_per_seed=[float(d) for d in spread.max(axis=1)]), args.out)


if __name__ == "__main__":
    main()
