"""Where one Car / Ant env step spends its time: the MJX stages, timed one by one.

For each robot the script builds the level-0 world, puts `--batch` worlds at the robot's start
pose (built on the host), runs `--warm` random-action env steps (so contacts are live), then
times, on whatever device JAX runs on:

  env step     `ZoneEnv.step_env` (physics, LiDAR, labels, termination), no auto-reset
  env own code the LiDAR, sensor read-out, labels and termination alone
  reset        (with `--reset`) `ZoneEnv.reset`, an exact layout and a forward pass; the batched
               auto-reset runs it for B/32 worlds a step
  kinematics   smooth.kinematics, com_pos, crb, factor_m (the mass matrix and its factor)
  collision    collision_driver.collision (C's capsule frame for the Ant, as `Physics` traces)
  constraint   constraint.make_constraint (contact and limit rows: efc_J, efc_D, efc_aref, ...)
  smooth       transmission, fwd_velocity, fwd_actuation, fwd_acceleration
  solver       solver.solve (Newton, the model's iteration and line-search caps)
  sensors      sensor_pos, sensor_vel, sensor_acc
  integration  the integrator's update after the forward pass (Euler: damping-implicit velocity
               and position update; RK4: the final combination, its stage evaluations are
               forward passes)

By default the first three are one stage ("position") and sensors and integration are the
"rest": the env step less its own code and the forward passes (one compile per chain, so `--fine`
costs 7 compiles instead of 3).

The MJX stages are timed as cumulative chains (kinematics; kinematics + collision; ...), each a
`vmap` over the batch inside a `lax.fori_loop` of `--loops` applications whose output is fed back
and whose own inputs (qpos, qvel, ctrl, qacc_warmstart) get a loop-variant zero added, so that
XLA cannot hoist work out of the loop; a stage's time is its chain's minus the previous chain's
(best of `--repeats` calls after a warm-up, per application; small stages can come out near 0 or
slightly negative in the noise). "x per env step" is how often the env step runs the stage
(Euler: 11 forward passes; RK4: 4 per substep + 1; sensors: once, unless the solver's
`substep_sensors`), and "share" that count times the stage's time over the env step's. Writes a
JSON to `--out` after each robot.

Usage: python benchmarks/zone_profile.py --robots Car Ant --batch 16384 --out /tmp/profile.json
       [--solver KEY=VALUE ...] (overrides of the robot's default `Solver`, e.g.
       max_contacts=0 substep_sensors=True for the settings before issue 18) [--reset]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import json
import platform
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import jaxlib
import mujoco
import numpy as np

from specrl_jax.envs.zone import contact_frame, make_zone, small_linalg
from specrl_jax.envs.zone.config import DEFAULT_SOLVERS, level_config
from specrl_jax.envs.zone.env import ZoneState
from specrl_jax.envs.zone.physics import PhysicsState

# isort: split
from mujoco.mjx._src import collision_driver, constraint, sensor, smooth, solver
from mujoco.mjx._src import forward as mjx_forward
from mujoco.mjx._src.types import IntegratorType


def _kinematics(m, d):
    for f in (smooth.kinematics, smooth.com_pos, smooth.camlight, smooth.tendon, smooth.crb,
              smooth.tendon_armature, smooth.factor_m):
        d = f(m, d)
    return d


def _smooth(m, d):
    d = smooth.transmission(m, d)
    for f in (mjx_forward.fwd_velocity, mjx_forward.fwd_actuation, mjx_forward.fwd_acceleration):
        d = f(m, d)
    return d


def _sensors(m, d):
    return sensor.sensor_acc(m, sensor.sensor_vel(m, sensor.sensor_pos(m, d)))


def _integration(m, d):
    if m.opt.integrator == IntegratorType.EULER:
        return mjx_forward.euler(m, d)
    return mjx_forward._advance(m, d, d.act_dot, d.qacc, d.qvel)


#: Cumulative prefixes of the forward pass; a stage's time is its prefix's minus the previous one.
FINE: tuple[tuple[str, Callable], ...] = (
    ("kinematics", _kinematics),
    ("collision", collision_driver.collision),
    ("constraint", constraint.make_constraint),
    ("smooth", _smooth),
    ("solver", solver.solve),
    ("sensors", _sensors),
    ("integration", _integration),
)
#: The default split (3 compiles instead of 7): what `--fine` times apart, grouped.
COARSE: tuple[tuple[str, Callable], ...] = (
    ("position", lambda m, d: constraint.make_constraint(
        m, collision_driver.collision(m, _kinematics(m, d)))),
    ("smooth", _smooth),
    ("solver", solver.solve),
)


def _best(fn: Callable, args: tuple, repeats: int) -> float:
    """Best wall seconds of `repeats` calls of a compiled `fn` after one warm-up call."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return min(times)


def _compile(fn: Callable, args: tuple, scope) -> tuple[Any, float]:
    start = time.perf_counter()
    with scope():
        compiled = jax.jit(fn).lower(*args).compile()
    return compiled, time.perf_counter() - start


def _start_states(env, batch: int, rng: np.random.Generator):
    """`ZoneState`s at the robots' start poses built on the host (zero velocity; no reset to
    compile): random positions and yaws, the Ant's joint noise, random zone centres."""
    robot = env.config.robot
    yaw = rng.uniform(0, 2 * np.pi, batch)
    if robot == "Point":
        qpos = np.stack([rng.uniform(-2, 2, batch), rng.uniform(-2, 2, batch), yaw], 1)
    else:
        joints = {"Car": np.tile([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], (batch, 1)),
                  "Ant": np.array([0, 1, 0, -1, 0, -1, 0, 1]) * np.pi / 2
                  + rng.uniform(-0.1, 0.1, (batch, 8))}[robot]
        qpos = np.concatenate([
            rng.uniform(-2, 2, (batch, 2)), np.full((batch, 1), env.start_height),
            np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1), joints], 1)
    qpos = jnp.asarray(qpos, env.physics.dtype)
    nv, nsensor = env.mj_model.nv, env.mj_model.nsensordata
    zeros = lambda *shape: jnp.zeros((batch, *shape), env.physics.dtype)
    num_zones = env.zone_color.shape[0]
    return ZoneState(
        physics=PhysicsState(qpos=qpos, qvel=zeros(nv), qacc_warmstart=zeros(nv),
                             agent_pos=zeros(3), agent_mat=zeros(3, 3), sensordata=zeros(nsensor)),
        start_qpos=qpos,
        zone_xy=jnp.asarray(rng.uniform(-2, 2, (batch, num_zones, 2)), jnp.float32),
        zone_direction=jnp.zeros((batch, num_zones)), zone_phase=jnp.zeros((batch, num_zones)),
        time=jnp.zeros(batch, jnp.int32),
    )


def profile(robot: str, batch: int, warm: int, loops: int, repeats: int,
            overrides: dict[str, Any], with_reset: bool, fine: bool) -> dict[str, Any]:
    """Per-stage timings of one robot's env step (see the module docstring)."""
    solver_cfg = dataclasses.replace(DEFAULT_SOLVERS[robot], **overrides)
    env, params = make_zone(level_config(robot, 0, solver=solver_cfg, physics="jax"))  # MJX-JAX's stages
    physics = env.physics
    @contextlib.contextmanager
    def scope():  # what `Physics.advance` opens around its tracing
        with contextlib.ExitStack() as stack:
            if physics.c_contact_frame:
                stack.enter_context(contact_frame.c_contact_frame())
            if physics.small_cholesky:
                stack.enter_context(small_linalg.small_cholesky())
            yield
    rows: dict[str, dict[str, float]] = {}
    key_reset, key_act = jax.random.split(jax.random.key(0))
    if with_reset:
        keys = jax.random.split(key_reset, batch)
        reset, reset_s = _compile(jax.vmap(env.reset, in_axes=(0, None)), (keys, params), scope)
        rows["reset"] = {"ms": 1e3 * _best(reset, (keys, params), repeats),
                         "compile_s": reset_s, "count": 1 / 32}
    state = _start_states(env, batch, np.random.default_rng(0))
    actions = jax.random.uniform(key_act, (batch, env.robot.action_dim), minval=-1, maxval=1)
    step_keys = jax.random.split(key_act, batch)
    env_step = jax.vmap(env.step_env, in_axes=(0, 0, 0, None))
    env_step_c, env_step_s = _compile(env_step, (step_keys, state, actions, params), scope)
    for _ in range(warm):  # from rest into contact: the Ant drops 2 cm onto its feet
        _, state, *_ = env_step_c(step_keys, state, actions, params)
    rows["env step"] = {"ms": 1e3 * _best(env_step_c, (step_keys, state, actions, params),
                                           repeats), "compile_s": env_step_s, "count": 1}

    def own(s):
        return env._observe(s), env._labels(s), s.physics.agent_pos[2]

    own_c, own_s = _compile(jax.vmap(own), (state,), scope)
    rows["env own code"] = {"ms": 1e3 * _best(own_c, (state,), repeats), "compile_s": own_s,
                            "count": 1}
    model = physics.model
    data = jax.vmap(lambda s, a: physics._template.replace(
        qpos=s.qpos, qvel=s.qvel, qacc_warmstart=s.qacc_warmstart,
        ctrl=jnp.asarray(a, physics.dtype)))(state.physics, actions)
    rk4 = model.opt.integrator == IntegratorType.RK4
    forwards = 10 * (4 if rk4 else 1) + 1
    counts = {"integration": 10, "sensors": forwards if solver_cfg.substep_sensors else 1}
    previous = 0.0
    stages = FINE if fine else COARSE
    for k, (name, _) in enumerate(stages):
        chain = [stage for _, stage in stages[:k + 1]]

        def looped(d, chain=chain):
            def body(i, x):
                # the forward pass's own inputs plus a loop-variant zero, so that XLA cannot
                # hoist the chain out of the loop (its output is fed back as well)
                zero = i.astype(physics.dtype) * 0.0
                x = x.replace(qpos=x.qpos + zero, qvel=x.qvel + zero, ctrl=x.ctrl + zero,
                              qacc_warmstart=x.qacc_warmstart + zero)

                def one(y):
                    for stage in chain:
                        y = stage(model, y)
                    return y

                return jax.vmap(one)(x)

            return jax.lax.fori_loop(0, loops, body, d)

        compiled, compile_s = _compile(looped, (data,), scope)
        ms = 1e3 * _best(compiled, (data,), repeats) / loops
        rows[name] = {"ms": ms - previous, "compile_s": compile_s,
                      "count": counts.get(name, forwards)}
        previous = ms
        print(f"  {robot} {name}: {rows[name]['ms']:.3f} ms (chain {ms:.3f} ms)", flush=True)
    total = rows["env step"]["ms"]
    if not fine:  # the rest: sensors (once), integration and the integrator's glue
        rest = total - rows["env own code"]["ms"] - forwards * previous
        rows["rest (sensors, integration)"] = {"ms": rest, "compile_s": 0.0, "count": 1}
    for row in rows.values():
        row["share"] = row["ms"] * row["count"] / total
    impl = data._impl
    return {
        "robot": robot, "batch": batch, "solver": dataclasses.asdict(solver_cfg),
        "contact_slots": int(impl.contact.dist.shape[-1]), "constraint_rows": int(
            impl.efc_J.shape[-2]), "forwards_per_env_step": forwards,
        "env_steps_per_s": batch / (total / 1e3), "stages": rows,
    }


def _parse_overrides(pairs: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        if value in ("True", "False"):
            out[key] = value == "True"
        else:
            try:
                out[key] = int(value)
            except ValueError:
                out[key] = value
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["Car", "Ant"])
    parser.add_argument("--batch", type=int, default=16384)
    parser.add_argument("--warm", type=int, default=10, help="env steps before timing")
    parser.add_argument("--loops", type=int, default=10, help="stage applications per call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--solver", nargs="*", default=[], metavar="KEY=VALUE",
                        help="Solver field overrides on top of the robot's default")
    parser.add_argument("--fine", action="store_true",
                        help="time the 7 stages apart (7 compiles; default: position, smooth, "
                        "solver and the rest)")
    parser.add_argument("--reset", action="store_true",
                        help="also time (and compile) the vmapped exact reset")
    parser.add_argument("--out", required=True, help="JSON output path")
    args = parser.parse_args()
    overrides = _parse_overrides(args.solver)
    device = jax.devices()[0]
    meta = {
        "device": f"{device.platform}: {device.device_kind}", "jax": jax.__version__,
        "jaxlib": jaxlib.__version__, "mujoco": mujoco.__version__,
        "python": platform.python_version(), "date": datetime.date.today().isoformat(),
        "solver_overrides": overrides, "results": [],
    }
    for robot in args.robots:
        start = time.perf_counter()
        r = profile(robot, args.batch, args.warm, args.loops, args.repeats, overrides,
                    args.reset, args.fine)
        r["wall_s"] = time.perf_counter() - start
        meta["results"].append(r)
        with open(args.out, "w") as f:  # after each robot, so a timeout keeps what was measured
            json.dump(meta, f, indent=1)
        print(f"\n{robot}, batch {args.batch}, {r['contact_slots']} contact slots, "
              f"{r['constraint_rows']} constraint rows, {r['forwards_per_env_step']} forward "
              f"passes per env step; env step {r['stages']['env step']['ms']:.2f} ms = "
              f"{r['env_steps_per_s']:,.0f} env-steps/s (no reset); {r['wall_s']:.0f} s")
        print(f"| stage | ms per call | x per env step | share of env step | compile s |")
        print("|---|---|---|---|---|")
        for name, row in r["stages"].items():
            print(f"| {name} | {row['ms']:.3f} | {row['count']:g} | {100 * row['share']:.1f}% | "
                  f"{row['compile_s']:.1f} |")


if __name__ == "__main__":
    main()
