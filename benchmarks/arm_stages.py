"""Where an arm physics substep spends its time: each stage jitted alone over a batch of arms.

The arms are at the states a rollout of uniformly random actions from the neutral pose reaches
(some touch the table by then). Each stage runs on the previous stage's output, so the rows are
the pieces of one substep (`Physics.substep`); the gated and every-arm substeps close the table.
A physics step (one env step) is 20 substeps; the last two rows time it whole, gated and with
no collision or constraint solve at all (the floor that no contact-side change can go below).
`--steps-only` times those two rows alone. Writes a JSON file and prints a Markdown table:

    python benchmarks/arm_stages.py --batch 4096 --steps 30 --out arm_stages.json
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.env import ACTION_SCALE
from specrl_jax.envs.arm.physics import Physics, motor_torque, spd_inverse
from specrl_jax.envs.zone import small_linalg
from specrl_jax.envs.zone.mjx_import import mjx


def timed(function, *args, repeats: int) -> tuple[float, object]:
    """Median ms of `repeats` calls of the jitted `function(*args)` after a first (compiling)
    call, and its output."""
    function = jax.jit(function)
    with small_linalg.small_cholesky():  # as inside `Physics.step`: written-out Cholesky
        out = jax.block_until_ready(function(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function(*args))
        times.append(1000 * (time.perf_counter() - start))
    return float(np.median(times)), out


def contact_free_step(physics: Physics, state, target: jax.Array):
    """`physics.step` with every substep taking the unconstrained acceleration: no collision,
    no constraint rows, no solve."""

    def substep(_, carry):
        data = physics._template.replace(qpos=carry.qpos, qvel=carry.qvel)
        data = physics.accelerate(data, target, carry.qfrc_constraint)
        data = mjx.euler(physics.model, data.replace(qacc=data.qacc_smooth))
        return carry.replace(qpos=data.qpos, qvel=data.qvel)

    with small_linalg.small_cholesky():
        return jax.lax.fori_loop(0, physics.substeps, substep, state)


def profile(num_envs: int, num_steps: int, repeats: int, steps_only: bool = False) -> dict:
    gated = Physics(arm_model.load_model(), arm_model.FORCE_LIMITS)
    every = Physics(arm_model.load_model(), arm_model.FORCE_LIMITS, solve_capacities=None,
                    solve_pairs=None)
    m, h = gated.model, float(gated.mj_model.opt.timestep)

    def act(s, a):  # one env step of physics for action `a` (the rollout's and the timed row's)
        return gated.step(s, s.qpos + ACTION_SCALE * a)

    step = jax.jit(jax.vmap(act))
    state = jax.vmap(gated.init)(jnp.tile(jnp.asarray(arm_model.NEUTRAL_QPOS, jnp.float32),
                                          (num_envs, 1)))
    keys = jax.random.split(jax.random.key(5), num_steps)
    for key in keys:
        action = jax.random.uniform(key, (num_envs, 7), minval=-1, maxval=1)
        state = step(state, action)
    target = state.qpos + ACTION_SCALE * action
    start = jax.vmap(lambda s: gated._template.replace(
        qpos=s.qpos, qvel=s.qvel, qacc_warmstart=s.qacc_warmstart))(state)
    limits = jnp.asarray(gated.force_limit)
    joint_range = jnp.asarray(gated.joint_range)

    def motor(data, target):
        mass = mjx.full_m(m, data)
        inverse = spd_inverse(mass)
        free_accel = inverse @ (data.qfrc_passive - data.qfrc_bias)
        return motor_torque(mass, free_accel, data.qvel, data.qpos, target, limits, h,
                            inverse=inverse, joint_range=joint_range)

    rows = {}

    def row(name, function, *args):
        ms, out = timed(jax.vmap(function), *args, repeats=repeats)
        rows[name] = round(ms, 3)
        print(f"{name}: {ms:.3f} ms", flush=True)
        return out

    if steps_only:
        needs = row("needs-solver test (ContactReach)", lambda s: needs_solver(
            gated, gated.accelerate(gated.data(s), s.qpos, s.qfrc_constraint)), state)
    else:
        needs = stage_rows(row, gated, every, m, start, target, state, motor)
    row("physics step (20 substeps), gated (the default)", act, state, action)
    row("physics step (20 substeps), no collision or constraint solve",
        lambda s, a: contact_free_step(gated, s, s.qpos + ACTION_SCALE * a), state, action)
    return {"batch": num_envs, "rollout_steps": num_steps, "repeats": repeats,
            "need_share": float(jnp.mean(needs)), "ms": rows}


def needs_solver(physics: Physics, data) -> jax.Array:
    """bool: whether the arm at `data` (after `accelerate`) runs the collision and solve."""
    return physics._needs_solver((data, physics._reach.gaps(data)))


def stage_rows(row, gated: Physics, every: Physics, m, start, target, state, motor) -> jax.Array:
    """The per-substep rows; returns which arms need the solve."""
    row("kinematics (chain frames)", gated.kinematics.fill, start)
    positioned = row("position stage (kinematics, com, crb, factor_m)", gated.position_stage,
                     start)
    moving = row("fwd_velocity (bias forces)", lambda d: mjx.fwd_velocity(m, d), positioned)
    row("motor and limit rows (mass matrix, inverse, Gauss-Seidel)", motor, moving, target)
    accelerated = row("accelerate (all of the above, then fwd_acceleration)", gated.accelerate,
                      start, target, state.qfrc_constraint)
    needs = row("needs-solver test (ContactReach)", lambda d: needs_solver(gated, d), accelerated)
    collided = row("collision, every arm", lambda d: gated.collision.collide(m, d), accelerated)
    constrained = row("make_constraint, every arm", lambda d: mjx.make_constraint(m, d), collided)
    row("Newton solve, every arm", lambda d: mjx.solve(m, d), constrained)

    def nearest_pairs(d):
        pairs = jax.lax.top_k(-gated._reach.gaps(d), gated.solve_pairs)[1]
        return gated.collision.collide_pairs(m, d, pairs)

    collided = row(f"collision of the {gated.solve_pairs} nearest pairs, every arm", nearest_pairs,
                   accelerated)
    row(f"make_constraint and Newton solve, every arm, {gated.solve_pairs} nearest pairs",
        lambda d: mjx.solve(m, mjx.make_constraint(m, d)), collided)
    row("collision + constraint + solve, gated", gated._constrain, accelerated)
    row("euler", lambda d: mjx.euler(m, d.replace(qacc=d.qacc_smooth)), accelerated)
    row("substep, gated (the default)", gated.substep, start, target, state.qfrc_constraint)
    row("substep, every arm", every.substep, start, target, state.qfrc_constraint)
    return needs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=30,
                        help="uniform random env steps from the neutral pose before timing")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--steps-only", action="store_true",
                        help="time only the whole physics step, gated and contact-free")
    parser.add_argument("--out", default="arm_stages.json")
    args = parser.parse_args()
    result = {"device": str(jax.devices()[0].device_kind), "jax": jax.__version__,
              **profile(args.batch, args.steps, args.repeats, args.steps_only)}
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)
    print(f"\n{args.batch} arms on {result['device']}, {result['need_share']:.1%} of them needing "
          f"the solve\n\n| stage | ms |\n|---|---|")
    for name, ms in result["ms"].items():
        print(f"| {name} | {ms} |")


if __name__ == "__main__":
    main()
