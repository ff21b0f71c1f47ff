"""GPU-scale checks of the arm world: no NaN over long saturated rollouts, the per-joint
tracking gains under uniform random actions at a large batch (the reference's measurement), and
where the compile time goes (`--parts compile`: each piece of the env step lowered and compiled
alone, with the persistent compilation cache off), and what MJX's line-search length costs and
changes (`--parts linesearch`), and how close each line-search length keeps MJX to MuJoCo C over
saturated rollouts (`--parts ls_vs_c`, a CPU-sized check); the same two for the Newton solver's
iteration cap and tolerance (`--parts iterations`, with the Newton iterations MJX runs per substep,
and `--parts iter_vs_c`).

    python benchmarks/arm_checks.py --batch 4096 --steps 1000 --out arm_checks.json
    python benchmarks/arm_checks.py --parts compile --compile-batch 4 --out arm_compile.json
    python benchmarks/arm_checks.py --parts ls_vs_c --c-batch 256 --c-steps 150 --out arm_ls_c.json
    python benchmarks/arm_checks.py --parts iter_vs_c --c-batch 96 --c-steps 150 \
        --iterations 20 10 5 3 --tolerances 1e-6 1e-5 --out arm_iter_c.json
    python benchmarks/arm_checks.py --parts iterations --ls-batch 4096 --ls-steps 10 \
        --iterations 10 5 --tolerances 1e-5 --out arm_iterations.json

Each part prints a line when it starts and as it progresses, and the JSON file is rewritten after
every part, so a run cut short by a time limit still leaves what it measured.
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import sys
import time
from typing import Callable
from unittest import mock

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import specrl_jax
from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.env import ACTION_SCALE
from specrl_jax.envs.arm.model import NEUTRAL_QPOS
from specrl_jax.envs.arm.physics import (SOLVE_CAPACITIES, SUBSTEPS, Physics, PhysicsState,
                                         motor_torque)
from specrl_jax.envs.wrappers import batch as batch_env
from specrl_jax.envs.zone import small_linalg
from specrl_jax.envs.zone.mjx_import import mjx

mjx_solver = mjx._src.solver  # MJX's solver module (counting_solve), imported by mjx

REFERENCE_GAINS = (0.61, 0.50, 0.82, 0.82, 0.86, 0.877, 0.878)


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def saturated_rollout(env_id: str, num_envs: int, num_steps: int, bank: int,
                      chunk: int = 100) -> dict:
    """Auto-resetting rollout with actions of +-1 in every joint; reports NaN and bounds.
    Runs `chunk` steps per compiled call and reports after each."""
    start = time.perf_counter()
    env, params = specrl_jax.make(env_id)
    params = env.with_map_bank(jax.random.key(1), params, bank)
    log(f"{env_id}: bank of {bank} layouts in {time.perf_counter() - start:.1f} s")
    batched = batch_env(env, num_envs)
    _, state = jax.jit(batched.reset)(jax.random.key(0), params)

    def body(carry, key):
        state, bad, labels = carry
        key_action, key_step = jax.random.split(key)
        action = jnp.sign(jax.random.uniform(key_action, (num_envs, 7), minval=-1, maxval=1))
        obs, state, _, _, _, info = batched.step(key_step, state, action, params)
        finite = jnp.all(jnp.isfinite(obs["ego"])) & jnp.all(jnp.isfinite(obs["ap"]))
        return (state, bad | ~finite, labels + jnp.sum(info["propositions"], 0)), None

    run = jax.jit(lambda carry, keys: jax.lax.scan(body, carry, keys)[0])
    carry = (state, jnp.array(False), jnp.zeros(env.num_propositions, jnp.int32))
    keys = jax.random.split(jax.random.key(2), num_steps)
    start = time.perf_counter()
    for done in range(0, num_steps, chunk):
        carry = jax.block_until_ready(run(carry, keys[done:done + chunk]))
        log(f"{env_id}: {min(done + chunk, num_steps)}/{num_steps} steps of {num_envs} arms, "
            f"NaN so far {bool(carry[1])}, {time.perf_counter() - start:.1f} s incl. compile")
    state, bad, labels = carry
    q = np.asarray(state.physics.qpos)
    return {"env": env_id, "batch": num_envs, "steps": num_steps, "any_nan": bool(bad),
            "seconds_incl_compile": time.perf_counter() - start,
            "label_counts": dict(zip(env.propositions, np.asarray(labels).tolist())),
            "joint_in_limits": bool(((q >= env.joint_low - 0.02) & (q <= env.joint_high + 0.02)).all())}


def tracking_gains(num_envs: int, num_steps: int) -> dict:
    """Least squares of dq on 0.05 a_t and 0.05 a_{t-1} per joint, random uniform actions from
    the neutral pose, table contacts on (the registered model)."""
    env, _ = specrl_jax.make("PandaLTLReach0Joints-v0")
    physics = env.physics
    q0 = jnp.tile(jnp.asarray(NEUTRAL_QPOS, jnp.float32), (num_envs, 1))

    @jax.jit
    def rollout(key):
        state = jax.vmap(physics.init)(q0)
        actions = jax.random.uniform(key, (num_steps, num_envs, 7), minval=-1.0, maxval=1.0)

        def body(state, action):
            new = jax.vmap(physics.step)(state, state.qpos + 0.05 * action)
            return new, (new.qpos - state.qpos, jnp.abs(new.qvel))

        _, (dq, speed) = jax.lax.scan(body, state, actions)
        return actions, dq, speed

    actions, dq, speed = (np.asarray(x) for x in rollout(jax.random.key(5)))
    a = 0.05 * actions
    out = {"gains": [], "lags": [], "mean_abs_qvel": speed.mean((0, 1)).tolist()}
    for j in range(7):
        x = np.stack([a[1:, :, j].ravel(), a[:-1, :, j].ravel()], 1)
        g, lag = np.linalg.lstsq(x, dq[1:, :, j].ravel(), rcond=None)[0]
        out["gains"].append(float(g))
        out["lags"].append(float(lag))
    out["max_gain_error"] = float(np.abs(np.array(out["gains"]) - REFERENCE_GAINS).max())
    return out


def model_with_line_search(length: int) -> mujoco.MjModel:
    """The registered arm model (table contacts on) with `opt.ls_iterations = length`."""
    model = copy.deepcopy(arm_model.load_model())
    model.opt.ls_iterations = length
    return model


def line_search(num_envs: int, num_steps: int, lengths: list[int]) -> dict:
    """The physics step with MJX's constraint solver at other line-search lengths
    (`opt.ls_iterations`, against MuJoCo's 50): MJX runs every line search as a scan of that many
    iterations (no-ops after convergence, which under `vmap` still cost a full iteration), so
    the length sets much of a substep's time while results should not depend on it
    (`settings_timing`)."""
    models = {str(n): model_with_line_search(n) for n in [50, *lengths]}
    return settings_timing(models, "50", num_envs, num_steps)


def settings_timing(models: dict[str, mujoco.MjModel | Physics], baseline: str, num_envs: int,
                    num_steps: int, counting: bool = False, actions: np.ndarray | None = None,
                    probe: Callable | None = None) -> dict:
    """The physics step at each setting (`models[name]`, a model or its `Physics`): a rollout of
    `num_steps` of `actions` (float[T, B, 7]; default saturated random ones) at `num_envs` arms
    from the neutral pose (ms per env step after compile); then one env step from every state
    of the `baseline` rollout with each setting: how many states give bit-identical joint angles
    and the largest and 99.9th-percentile difference (rad). With `counting`, MJX's Newton
    iterations per substep over each setting's rollout (`iteration_summary`; a second rollout,
    by `counting_env_step`). With `probe` (batched states -> float), its value at each of the
    baseline rollout's states."""
    if actions is None:
        actions = np.asarray(jnp.sign(jax.random.uniform(
            jax.random.key(3), (num_steps, num_envs, 7), minval=-1, maxval=1)))
    physics = {name: m if isinstance(m, Physics) else Physics(m, arm_model.FORCE_LIMITS)
               for name, m in models.items()}
    start_state = jax.vmap(physics[baseline].init)(
        jnp.tile(jnp.asarray(NEUTRAL_QPOS, jnp.float32), (num_envs, 1)))
    out, visited, last = {}, [], {}
    for name in [baseline, *[n for n in physics if n != baseline]]:
        step = env_step(physics[name])
        start = time.perf_counter()
        state = jax.block_until_ready(step(start_state, actions[0]))
        compile_s = time.perf_counter() - start
        state = start_state
        start = time.perf_counter()
        for t in range(num_steps):
            if name == baseline:
                visited.append(state)
            state = step(state, actions[t])
        jax.block_until_ready(state)
        out[name] = {"ms_per_env_step": 1000 * (time.perf_counter() - start) / num_steps,
                     "first_call_s": compile_s}
        if counting:
            run = mjx_rollout(counting_env_step(physics[name]), start_state, np.asarray(actions))
            out[name]["newton_iterations"] = iteration_summary(run["newton_iterations"],
                                                               run["engaged"])
        if probe is not None and name == baseline:
            out[name]["probe_by_step"] = [round(float(probe(s)), 3) for s in visited]
        last[name] = step
        log(f"settings {name}: {json.dumps(out[name])}")
    states = jax.tree.map(lambda *x: jnp.concatenate(x), *visited)
    flat_actions = jnp.asarray(actions.reshape(-1, 7))
    reference = np.asarray(last[baseline](states, flat_actions).qpos)
    for name, row in out.items():
        if name != baseline:
            diff = np.abs(np.asarray(last[name](states, flat_actions).qpos) - reference).max(1)
            row.update(states=int(diff.size), identical=int((diff == 0).sum()),
                       max_abs_dq=float(diff.max()), p999_abs_dq=float(np.quantile(diff, 0.999)))
            log(f"settings {name} against {baseline}: {json.dumps(row)}")
    return out


def capacity_timing(num_envs: int, num_steps: int, capacities: list[float | str],
                    pairs: list[int | None] = ()) -> dict:
    """The physics step with the collision and solver gathered for the arms that need them, one
    sub-batch size per run (`Physics(solve_capacities=(c,))`; "default": the model's
    `SOLVE_CAPACITIES`), and at the default sizes with the collision and solve over each of
    `pairs` nearest contact pairs (None: all), against every arm over every pair ("None"), under
    uniform random and saturated actions (`settings_timing`); "None"'s `probe_by_step` is the
    share of arms that needed the solver (`ContactReach`) at each step."""
    model = arm_model.load_model()
    tiers = lambda c: SOLVE_CAPACITIES if c == "default" else (c,)
    physics = {"None": Physics(model, arm_model.FORCE_LIMITS, solve_capacities=None,
                               solve_pairs=None),
               **{str(c): Physics(model, arm_model.FORCE_LIMITS, solve_capacities=tiers(c))
                  for c in capacities},
               **{f"default, {k or 'all'} pairs": Physics(model, arm_model.FORCE_LIMITS,
                                                           solve_pairs=k)
                  for k in pairs}}
    gated = physics[str(capacities[0])]

    def needs(state: PhysicsState) -> jax.Array:
        data = gated.data(state)
        return gated._needs_solver((data, gated._reach.gaps(data)))

    share = jax.jit(lambda s: jnp.mean(jax.vmap(needs)(s)))
    key = jax.random.key(4)
    actions = {"uniform": np.asarray(jax.random.uniform(key, (num_steps, num_envs, 7),
                                                        minval=-1, maxval=1)),
               "saturated": saturated_actions(key, num_steps, num_envs)}
    return {kind: settings_timing(physics, "None", num_envs, num_steps, actions=a, probe=share)
            for kind, a in actions.items()}


def saturated_actions(key: jax.Array, num_steps: int, num_envs: int) -> np.ndarray:
    """float32[T, B, 7] actions of +-1; each arm and joint draws its probability of +1 from
    U(0.1, 0.9), so arms drift (into joint limits, the table and the floor) as well as jitter."""
    key_bias, key_sign = jax.random.split(key)
    bias = jax.random.uniform(key_bias, (num_envs, 7), minval=0.1, maxval=0.9)
    up = jax.random.uniform(key_sign, (num_steps, num_envs, 7)) < bias
    return np.asarray(jnp.where(up, 1.0, -1.0), np.float32)


def c_rollout(model: mujoco.MjModel, start: PhysicsState, actions: np.ndarray) -> dict:
    """The env's control law on MuJoCo C (float64): each env step the joint targets
    `q + 0.05 a`, then per substep `mj_step1`, the motor and joint-limit forces of
    `physics.motor_torque` (run in float64) from C's mass matrix and bias forces, and `mj_step2`.

    Args:
        model: the MuJoCo model (its `opt` is C's solver setting).
        start: batched `PhysicsState` (float[B, 7] each) to start from.
        actions: float[T, B, 7].

    Returns `qpos`, `qvel`, `qacc_warmstart`, `qfrc_constraint` float64[T + 1, B, 7] and, per
    env step int32[T, B], the most contacts (`ncon`), joint-limit rows (`nl`), Newton
    iterations and line-search cost evaluations of one substep (`ls_evals`: the most in one
    Newton iteration).
    """
    num_steps, num_envs = actions.shape[:2]
    datas = [mujoco.MjData(model) for _ in range(num_envs)]
    for i, data in enumerate(datas):
        data.qpos[:], data.qvel[:] = np.asarray(start.qpos[i]), np.asarray(start.qvel[i])
        data.qacc_warmstart[:] = np.asarray(start.qacc_warmstart[i])
        data.qfrc_constraint[:] = np.asarray(start.qfrc_constraint[i])
    limit = np.asarray(arm_model.FORCE_LIMITS, np.float64)
    with jax.enable_x64(True):
        joint_range = jnp.asarray(model.jnt_range[:7])
        torque = jax.jit(jax.vmap(functools.partial(motor_torque, h=float(model.opt.timestep),
                                                    joint_range=joint_range),
                                  in_axes=(0, 0, 0, 0, 0, None)))
        fields = ("qpos", "qvel", "qacc_warmstart", "qfrc_constraint")
        out = {k: np.zeros((num_steps + 1, num_envs, model.nv)) for k in fields}
        stats = {k: np.zeros((num_steps, num_envs), np.int32)
                 for k in ("ncon", "nl", "newton_iterations", "ls_evals")}
        mass = np.zeros((num_envs, model.nv, model.nv))
        for t in range(num_steps + 1):
            for k in fields:
                out[k][t] = [getattr(d, k) for d in datas]
            if t == num_steps:
                break
            target = out["qpos"][t] + ACTION_SCALE * actions[t]
            for _ in range(SUBSTEPS):
                for i, data in enumerate(datas):
                    mujoco.mj_step1(model, data)
                    mujoco.mj_fullM(model, data, mass[i])
                # the previous substep's constraint forces count as known, as in `Physics.substep`
                bias = np.asarray([d.qfrc_passive - d.qfrc_bias + d.qfrc_constraint
                                   for d in datas])
                qvel = np.asarray([d.qvel for d in datas])
                qpos = np.asarray([d.qpos for d in datas])
                tau = np.asarray(torque(mass, np.linalg.solve(mass, bias[..., None])[..., 0],
                                        qvel, qpos, target, limit))
                for i, data in enumerate(datas):
                    data.qfrc_applied[:] = tau[i]
                    mujoco.mj_step2(model, data)
                    niter = int(data.solver_niter.sum())
                    row = (data.ncon, data.nl, niter,
                           int(data.solver.neval[:max(niter, 1)].max()))
                    for k, v in zip(stats, row):
                        stats[k][t, i] = max(stats[k][t, i], v)
    return {**out, **stats}


def env_step(physics: Physics):
    """The jitted batched physics step under the env's control law: `(state, action float[B, 7])
    -> state` with joint targets `q + 0.05 a`."""
    return jax.jit(jax.vmap(lambda s, a: physics.step(s, s.qpos + ACTION_SCALE * a)))


def counting_solve(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mjx.solve` (mujoco 4.0.0's `mjx/_src/solver.py`, Newton, no CG branch) that also leaves its
    Newton iteration count in `d._impl.solver_niter` (MJX's drops it): the same warm start,
    loop condition and body, built from the module's own pieces."""
    def cond(ctx):
        improvement = mjx_solver._rescale(m, d, ctx.prev_cost - ctx.cost)
        gradient = mjx_solver._rescale(m, d, mjx_solver.math.norm(ctx.grad))
        done = ctx.solver_niter >= m.opt.iterations
        done |= improvement < m.opt.tolerance
        done |= gradient < m.opt.tolerance
        return ~done

    def body(ctx):
        ctx = mjx_solver._linesearch(m, d, ctx)
        ctx = mjx_solver._update_gradient(m, d, mjx_solver._update_constraint(m, d, ctx))
        return ctx.replace(search=-ctx.Mgrad, solver_niter=ctx.solver_niter + 1)

    assert m.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON and m.opt.iterations > 1
    warm = mjx_solver.Context.create(m, d.replace(qacc=d.qacc_warmstart), grad=False)
    smooth = mjx_solver.Context.create(m, d.replace(qacc=d.qacc_smooth), grad=False)
    d = d.replace(qacc=jnp.where(warm.cost < smooth.cost, d.qacc_warmstart, d.qacc_smooth))
    ctx = jax.lax.while_loop(cond, body, mjx_solver.Context.create(m, d))
    return d.tree_replace({"qfrc_constraint": ctx.qfrc_constraint, "qacc": ctx.qacc,
                           "_impl.efc_force": ctx.efc_force,
                           "_impl.solver_niter": ctx.solver_niter})


def counted_step(physics: Physics, state: PhysicsState, target: jax.Array
                 ) -> tuple[PhysicsState, jax.Array, jax.Array]:
    """`physics.step` for one arm with `counting_solve`: the new state, the Newton iterations of
    each substep int32[S], and what each substep engaged int32[S] (2: a contact at negative
    distance, 1: a joint past its limit and no contact, 0: neither)."""
    low, high = physics.mj_model.jnt_range.T

    def substep(i, carry):
        state, niter, engaged = carry
        data = physics.data(state).replace(qacc_warmstart=state.qacc_warmstart)
        data = physics.accelerate(data, target, state.qfrc_constraint)
        with mock.patch.object(mjx, "solve", counting_solve):
            solved = physics.solved(data)
        data = mjx.euler(physics.model, solved)
        limit = jnp.any((state.qpos < low) | (state.qpos > high))
        kind = jnp.where(jnp.any(solved._impl.contact.dist < 0), 2, jnp.where(limit, 1, 0))
        state = PhysicsState(qpos=data.qpos, qvel=data.qvel, qacc_warmstart=data.qacc_warmstart,
                             qfrc_constraint=data.qfrc_constraint)
        return state, niter.at[i].set(solved._impl.solver_niter), engaged.at[i].set(kind)

    zeros = jnp.zeros(physics.substeps, jnp.int32)
    with small_linalg.small_cholesky():
        return jax.lax.fori_loop(0, physics.substeps, substep, (state, zeros, zeros))


def counting_env_step(physics: Physics):
    """`env_step` that also returns the Newton iterations and what was engaged per substep,
    int32[B, S] each (`counted_step`)."""
    return jax.jit(jax.vmap(
        lambda s, a: counted_step(physics, s, s.qpos + ACTION_SCALE * a)))


def iteration_summary(niter: np.ndarray, engaged: np.ndarray) -> dict:
    """MJX's Newton iterations per substep, `niter, engaged: int[T, B, S]`: a histogram overall
    and by what the substep engaged, and what a batch pays (a `vmap`ped while loop runs until
    its slowest arm is done): the mean over substeps of the slowest arm's count among groups
    of 1 (the mean), 16 and all B arms, and the most."""
    out = {"substeps": int(niter.size), "hist": np.bincount(niter.ravel()).tolist()}
    for code, kind in enumerate(("free", "limit only", "contact")):
        mask = engaged == code
        if mask.any():
            out[kind] = {"substeps": int(mask.sum()), "mean": float(niter[mask].mean()),
                         "max": int(niter[mask].max()),
                         "hist": np.bincount(niter[mask]).tolist()}
    num_steps, num_envs, substeps = niter.shape
    out["slowest_arm_mean"] = {}
    for group in sorted({1, 16, num_envs}):
        if num_envs % group == 0:
            grouped = niter.reshape(num_steps, num_envs // group, group, substeps).max(2)
            out["slowest_arm_mean"][str(group)] = float(grouped.mean())
    out["max"] = int(niter.max())
    return out


def counting_step_identical(plain: dict, counted: dict, ref: dict, actions: np.ndarray,
                            times: np.ndarray) -> dict:
    """Per name, how many of the states at `times` (C's, as `one_step_from_c`) give joint angles
    bit-identical under `counted[name]` and `plain[name]`, and of how many."""
    out = {}
    for name in counted:
        same = 0
        for t in times:
            state = PhysicsState(qpos=ref["qpos"][t].astype(np.float32),
                                 qvel=ref["qvel"][t].astype(np.float32),
                                 qacc_warmstart=ref["qacc_warmstart"][t].astype(np.float32),
                                 qfrc_constraint=ref["qfrc_constraint"][t].astype(np.float32))
            action = jnp.asarray(actions[t])
            a = np.asarray(plain[name](state, action).qpos)
            b = np.asarray(counted[name](state, action)[0].qpos)
            same += int((a == b).all(-1).sum())
        out[name] = [same, int(len(times) * actions.shape[1])]
    return out


def mjx_rollout(step, start: PhysicsState, actions: np.ndarray) -> dict:
    """`qpos`, `qvel` float32[T + 1, B, 7] of MJX from `start` under `actions` (float[T, B, 7]),
    one call of `step` (an `env_step`) per Python iteration; with a `counting_env_step`, also
    `newton_iterations` and `engaged` int32[T, B, S]."""
    state, rows = start, {"qpos": [start.qpos], "qvel": [start.qvel]}
    for action in actions:
        result = step(state, jnp.asarray(action))
        state, *counts = result if isinstance(result, tuple) else (result,)
        rows["qpos"].append(state.qpos)
        rows["qvel"].append(state.qvel)
        for key, value in zip(("newton_iterations", "engaged"), counts):
            rows.setdefault(key, []).append(value)
    return {key: np.asarray(jnp.stack(value)) for key, value in rows.items()}


def error_summary(err: np.ndarray, checkpoints: tuple[int, ...] = (10, 50, 100, 150)) -> dict:
    """Median, p99 and max of `err: float[T + 1, B]` (rad, largest joint) over every step after
    the start, a 95% interval of the median and p99 from resampling arms, and the same three at
    some steps."""
    pooled = err[1:]
    rng = np.random.default_rng(0)
    picks = rng.integers(0, err.shape[1], (200, err.shape[1]))
    boot = np.asarray([np.percentile(pooled[:, p], [50, 99]) for p in picks])
    row = {"median": float(np.median(pooled)), "p99": float(np.percentile(pooled, 99)),
           "max": float(pooled.max()),
           "median_95": np.percentile(boot[:, 0], [2.5, 97.5]).tolist(),
           "p99_95": np.percentile(boot[:, 1], [2.5, 97.5]).tolist()}
    for t in checkpoints:
        if t < len(err):
            row[f"step_{t}"] = [float(np.median(err[t])), float(np.percentile(err[t], 99)),
                                float(err[t].max())]
    return row


def label_summary(ours: np.ndarray, ref: np.ndarray) -> dict:
    """Agreement of mode-0 labels `ours`, `ref: bool[T + 1, B, P]`: steps whose label vectors
    differ, the true labels of each, and how many (arm, proposition) pairs first hold at the
    same step (or never) in both."""
    def first(labels):
        return np.where(labels.any(0), labels.argmax(0), -1)

    return {"steps": int(ref.shape[0] * ref.shape[1]),
            "steps_differing": int((ours != ref).any(-1).sum()),
            "true_ref": int(ref.sum()), "true_ours": int(ours.sum()),
            "true_both": int((ours & ref).sum()),
            "first_visits_ref": int((first(ref) >= 0).sum()),
            "first_visit_pairs_differing": int((first(ours) != first(ref)).sum())}


def one_step_from_c(steps: dict, ref: dict, actions: np.ndarray, times: np.ndarray,
                    baseline: str = "50") -> dict:
    """One env step from C's states (joint angles, velocities, warm start) at `times` with each
    `steps[name] = (env_step, nudge)` (`nudge`: joint angles one float32 step up); per name
    |q_MJX - q_C| (largest joint, rad) overall and by what C's step engaged, and against
    `baseline` (a name of `steps`) the bit-identical count and largest difference."""
    kind = np.where(ref["ncon"][times] > 0, "contact",
                    np.where(ref["nl"][times] > 0, "limit only", "free"))
    after, out = {}, {}
    for name, (step, nudge) in steps.items():
        qs = []
        for t in times:
            qpos = ref["qpos"][t].astype(np.float32)
            state = PhysicsState(
                qpos=np.nextafter(qpos, np.float32(np.inf)) if nudge else qpos,
                qvel=ref["qvel"][t].astype(np.float32),
                qacc_warmstart=ref["qacc_warmstart"][t].astype(np.float32),
                qfrc_constraint=ref["qfrc_constraint"][t].astype(np.float32))
            qs.append(np.asarray(step(state, jnp.asarray(actions[t])).qpos))
        after[name] = np.stack(qs)
        err = np.abs(after[name] - ref["qpos"][times + 1]).max(-1)
        row = {"states": int(err.size), "median": float(np.median(err)),
               "p99": float(np.percentile(err, 99)), "max": float(err.max())}
        for k in ("contact", "limit only", "free"):
            if (kind == k).any():
                row[k] = [int((kind == k).sum()), float(np.median(err[kind == k])),
                          float(np.percentile(err[kind == k], 99)), float(err[kind == k].max())]
        if name != baseline:
            diff = np.abs(after[name] - after[baseline]).max(-1)
            row.update({f"identical_to_{baseline}": int((diff == 0).sum()),
                        f"max_vs_{baseline}": float(diff.max()),
                        "differing_with_contact": int(((diff > 0) & (kind == "contact")).sum())})
        out[name] = row
        log(f"vs C: one step, {name}: {json.dumps(row)}")
    return out


def solver_vs_c(models: dict[str, mujoco.MjModel], baseline: str, c_reference: mujoco.MjModel,
                num_envs: int, num_steps: int, stride: int, counting: bool = False) -> dict:
    """MJX at each solver setting (`models[name]`) against MuJoCo C (float64, `c_reference`'s
    setting) under the same control law, `num_envs` arms from the neutral pose under
    `saturated_actions`:

    - `c_engaged`: what C's steps engaged, its Newton iterations and line-search cost
      evaluations per step;
    - `c_cap`: C itself at each other setting, largest |q - q_C| over the rollout;
    - `free`: free-running |q_MJX - q_C| (largest joint, rad) per setting, and `pairs`
      |q_MJX(name) - q_MJX(baseline)|, beside `rounding_twin`: MJX at `baseline` from joint
      angles one float32 step away (np.nextafter), the spread that rounding alone gives;
    - `labels`: mode-0 labels (regions of one bank layout per arm) against C's;
    - `one_step`: `one_step_from_c` every `stride` steps;
    - with `counting`, `newton_iterations`: MJX's Newton iterations per substep of each free
      run (`iteration_summary`), the runs stepped by `counting_env_step`, which is checked
      to give the joint angles of the plain step at every one-step state.
    """
    env, params = specrl_jax.make("PandaLTLReach0Joints-v0")
    regions = env.with_map_bank(jax.random.key(6), params, num_envs).layout_bank

    @jax.jit
    def labels(qpos):  # float[T, B, 7] -> bool[T, B, P]
        def one(q, centres):
            _, state = env.reset_to(None, {"region_pos": centres, "joint_qpos": q}, params)
            return env.label(state)
        return jax.vmap(jax.vmap(one), in_axes=(0, None))(qpos, regions)

    actions = saturated_actions(jax.random.key(4), num_steps, num_envs)
    neutral = np.tile(NEUTRAL_QPOS, (num_envs, 1)).astype(np.float32)
    start = PhysicsState(qpos=neutral, qvel=np.zeros_like(neutral),
                         qacc_warmstart=np.zeros_like(neutral),
                         qfrc_constraint=np.zeros_like(neutral))
    t0 = time.perf_counter()
    ref = c_rollout(c_reference, start, actions)
    log(f"vs C: C rollout {time.perf_counter() - t0:.0f} s")
    out = {"batch": num_envs, "steps": num_steps,
           "c_engaged": {"steps_with_contact": float((ref["ncon"] > 0).mean()),
                         "arms_with_contact": int((ref["ncon"] > 0).any(0).sum()),
                         "steps_with_limit": float((ref["nl"] > 0).mean()),
                         "newton_iterations_max": int(ref["newton_iterations"].max()),
                         "newton_iterations_hist": np.bincount(
                             ref["newton_iterations"].ravel()).tolist(),
                         "ls_evals_hist": np.bincount(ref["ls_evals"].ravel()).tolist()},
           "c_cap": {}, "free": {}, "pairs": {}, "labels": {}}
    for name, model in models.items():
        if name != baseline:
            short = c_rollout(model, start, actions)
            out["c_cap"][name] = float(np.abs(short["qpos"] - ref["qpos"]).max())
            log(f"vs C: C at {name}: {out['c_cap'][name]}")
    ref_labels = np.asarray(labels(ref["qpos"]))

    physics = {name: Physics(model, arm_model.FORCE_LIMITS) for name, model in models.items()}
    compiled = {name: env_step(p) for name, p in physics.items()}
    steps = {name: (compiled[name], False) for name in models}
    steps["rounding_twin"] = (compiled[baseline], True)
    if counting:
        counted = {name: counting_env_step(p) for name, p in physics.items()}
        out["newton_iterations"] = {}
    runs = {}
    for name, (step, nudge) in steps.items():
        t0 = time.perf_counter()
        first = start.replace(qpos=np.nextafter(neutral, np.float32(np.inf))) if nudge else start
        runs[name] = mjx_rollout(counted[name if not nudge else baseline] if counting else step,
                                 first, actions)
        out["free"][name] = error_summary(np.abs(runs[name]["qpos"] - ref["qpos"]).max(-1))
        out["free"][name]["seconds"] = time.perf_counter() - t0
        out["labels"][name] = label_summary(np.asarray(labels(runs[name]["qpos"])), ref_labels)
        if counting:
            out["newton_iterations"][name] = iteration_summary(runs[name]["newton_iterations"],
                                                               runs[name]["engaged"])
        if name != baseline:
            out["pairs"][name] = error_summary(
                np.abs(runs[name]["qpos"] - runs[baseline]["qpos"]).max(-1))
        log(f"vs C: MJX {name}: {json.dumps(out['free'][name])} labels "
            f"{json.dumps(out['labels'][name])}")
    times = np.arange(0, num_steps, stride)
    out["one_step"] = one_step_from_c(steps, ref, actions, times, baseline)
    if counting:
        out["counting_step_identical"] = counting_step_identical(compiled, counted, ref, actions,
                                                                 times)
        log(f"vs C: counting step identical: {json.dumps(out['counting_step_identical'])}")
    return out


def line_search_vs_c(num_envs: int, num_steps: int, lengths: list[int], stride: int) -> dict:
    """`solver_vs_c` over MJX's line-search lengths (`opt.ls_iterations`) against MuJoCo's 50,
    C at 50."""
    models = {str(n): model_with_line_search(n) for n in [50, *lengths]}
    return solver_vs_c(models, "50", models["50"], num_envs, num_steps, stride)


def model_with_solver(iterations: int, tolerance: float, ls_iterations: int | None = None
                      ) -> mujoco.MjModel:
    """The registered arm model with the Newton solver's `opt.iterations` and `opt.tolerance`
    (and `opt.ls_iterations` if given; otherwise `assets/panda.xml`'s)."""
    model = copy.deepcopy(arm_model.load_model())
    model.opt.iterations, model.opt.tolerance = iterations, tolerance
    if ls_iterations is not None:
        model.opt.ls_iterations = ls_iterations
    return model


def solver_settings(iterations: list[int], tolerances: list[float]) -> dict[str, tuple]:
    """Named `(iterations, tolerance)` settings: MuJoCo's default "100/1e-08" first, then each
    cap at 1e-8 and each tolerance at 100 iterations."""
    pairs = [(100, 1e-8), *[(n, 1e-8) for n in iterations], *[(100, t) for t in tolerances]]
    return {f"{n}/{t:.0e}": (n, t) for n, t in pairs}


def iterations_vs_c(num_envs: int, num_steps: int, iterations: list[int],
                    tolerances: list[float], stride: int) -> dict:
    """`solver_vs_c` over the Newton solver's iteration cap and tolerance (MJX's line search as
    in `assets/panda.xml`) against MuJoCo's defaults 100 / 1e-8, C at MuJoCo's defaults
    (line search 50 too), with MJX's Newton iterations counted; then those iterations under
    uniform random actions at the default setting (`random_actions`)."""
    settings = solver_settings(iterations, tolerances)
    models = {name: model_with_solver(*setting) for name, setting in settings.items()}
    out = solver_vs_c(models, "100/1e-08", model_with_solver(100, 1e-8, ls_iterations=50),
                      num_envs, num_steps, stride, counting=True)
    physics = Physics(models["100/1e-08"], arm_model.FORCE_LIMITS)
    actions = np.asarray(jax.random.uniform(jax.random.key(7), (num_steps, num_envs, 7),
                                            minval=-1.0, maxval=1.0))
    neutral = np.tile(NEUTRAL_QPOS, (num_envs, 1)).astype(np.float32)
    start = PhysicsState(qpos=neutral, qvel=np.zeros_like(neutral),
                         qacc_warmstart=np.zeros_like(neutral),
                         qfrc_constraint=np.zeros_like(neutral))
    run = mjx_rollout(counting_env_step(physics), start, actions)
    out["random_actions"] = iteration_summary(run["newton_iterations"], run["engaged"])
    log(f"iter_vs_c: random actions: {json.dumps(out['random_actions'])}")
    return out


PIECES = ("kinematics", "substep", "physics_step", "observe_mode0", "observe_mode1", "ik",
          "keepout_test", "exact_reset", "layout_bank_256", "step_mode0", "rollout_bank_mode0",
          "rollout_bank_mode1", "rollout_exact_mode0")


def compile_pieces(num_envs: int, num_steps: int, pieces: list[str] | None = None) -> dict:
    """Seconds to lower and to compile each piece of the arm's programs at `num_envs` arms, and
    the size of its StableHLO (operations). The pieces nest: `rollout_*` is what
    `env_throughput.py` compiles (a scan of `num_steps` auto-resetting steps: physics step,
    observation, and the reset twice, once per branch of `BatchedAutoReset`)."""
    import env_throughput  # beside this script
    from jax.experimental.compilation_cache import compilation_cache

    from specrl_jax.envs.arm import layout as layout_lib

    # importing specrl_jax switched the persistent cache on (and compiled through it): off and
    # reset, so every piece compiles afresh
    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()
    env0, params0 = specrl_jax.make("PandaLTLReach0Joints-v0")
    env1, _ = specrl_jax.make("PandaLTLReach1Joints-v0")
    env_ee, _ = specrl_jax.make("PandaLTLReach0-v0")
    key = jax.random.key(0)
    keys = jax.random.split(key, num_envs)
    physics = env0.physics
    neutral = jnp.tile(jnp.asarray(NEUTRAL_QPOS, jnp.float32), (num_envs, 1))
    phys = jax.jit(jax.vmap(physics.init))(neutral)
    bank = jnp.tile(jnp.asarray([[0.1 * z, 0.2, 0.3] for z in range(8)], jnp.float32), (16, 1, 1))
    bank_params = params0.replace(layout_bank=bank)

    def states(env):
        _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, bank_params)
        return state

    def rollout(env, params):
        batched = batch_env(env, num_envs)
        _, state = jax.jit(batched.reset)(key, params)
        run = env_throughput.make_rollout(batched, params, num_steps)
        return run, (key, state)

    def substep(data, target, qfrc_constraint):
        with small_linalg.small_cholesky():  # as inside `physics.step`: written-out Cholesky
            return physics.substep(data, target, qfrc_constraint)

    data = jax.jit(jax.vmap(physics.data))(phys)
    table = {
        "kinematics": lambda: (jax.vmap(physics.data), (phys,)),
        "substep": lambda: (jax.vmap(substep), (data, phys.qpos, phys.qfrc_constraint)),
        "physics_step": lambda: (jax.vmap(physics.step), (phys, phys.qpos)),
        "observe_mode0": lambda: (jax.vmap(env0._observe), (states(env0),)),
        "observe_mode1": lambda: (jax.vmap(env1._observe), (states(env1),)),
        "ik": lambda: (jax.vmap(env_ee.ik.joint_targets), (phys.qpos, phys.qpos[:, :3])),
        "keepout_test": lambda: (jax.vmap(lambda c: layout_lib.keepout_ok(c, env0.config)),
                                 (bank[0],)),
        "exact_reset": lambda: (jax.vmap(env0.reset, in_axes=(0, None)), (keys, params0)),
        "layout_bank_256": lambda: (lambda k: layout_lib.sample_bank(k, env0.config, 256), (key,)),
        "step_mode0": lambda: (jax.vmap(env0.step, in_axes=(0, 0, 0, None)),
                               (keys, states(env0), phys.qpos, bank_params)),
        "rollout_bank_mode0": lambda: rollout(env0, bank_params),
        "rollout_bank_mode1": lambda: rollout(env1, bank_params),
        "rollout_exact_mode0": lambda: rollout(env0, params0),
    }
    assert set(table) == set(PIECES)
    out = {}
    for name in pieces or PIECES:
        function, args = table[name]()
        start = time.perf_counter()
        lowered = (function if hasattr(function, "lower") else jax.jit(function)).lower(*args)
        lower_s = time.perf_counter() - start
        text = lowered.as_text()
        start = time.perf_counter()
        lowered.compile()
        out[name] = {"lower_s": round(lower_s, 2), "compile_s": round(time.perf_counter() - start, 2),
                     "stablehlo_ops": sum(line.lstrip().startswith("%") for line in text.splitlines())}
        log(f"compile {name}: {json.dumps(out[name])}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--bank-size", type=int, default=4096)
    parser.add_argument("--envs", nargs="+", help="nan: the arm worlds to roll out",
                        default=["PandaLTLReach0Joints-v0", "PandaLTLReach1Joints-v0"])
    parser.add_argument("--gain-batch", type=int, default=256)
    parser.add_argument("--gain-steps", type=int, default=400)
    parser.add_argument("--parts", nargs="+",
                        choices=("gains", "nan", "compile", "linesearch", "ls_vs_c",
                                 "iterations", "iter_vs_c", "capacity"),
                        default=("gains", "nan"))
    parser.add_argument("--ls-batch", type=int, default=4096, help="linesearch, iterations")
    parser.add_argument("--ls-steps", type=int, default=20, help="linesearch, iterations")
    parser.add_argument("--ls-lengths", type=int, nargs="+", default=[10, 5])
    parser.add_argument("--iterations", type=int, nargs="+", default=[20, 10, 5, 3],
                        help="iterations, iter_vs_c: Newton iteration caps (at tolerance 1e-8)")
    parser.add_argument("--tolerances", type=float, nargs="+", default=[1e-6, 1e-5],
                        help="iterations, iter_vs_c: Newton tolerances (at 100 iterations)")
    parser.add_argument("--capacities", nargs="+", default=["default", "0.25"],
                        help="capacity: sub-batch shares to time against None (every arm)")
    parser.add_argument("--pairs", nargs="*", default=[],
                        help="capacity: collisions and solves over this many nearest contact "
                             "pairs ('all': every one) to time at the default sub-batch sizes")
    parser.add_argument("--c-batch", type=int, default=256)
    parser.add_argument("--c-steps", type=int, default=150)
    parser.add_argument("--c-stride", type=int, default=5,
                        help="ls_vs_c: one env step from C's states every this many steps")
    parser.add_argument("--compile-batch", type=int, default=4)
    parser.add_argument("--compile-steps", type=int, default=50)
    parser.add_argument("--pieces", nargs="+", choices=PIECES, default=None,
                        help="compile: these pieces only (default all)")
    parser.add_argument("--out", default="arm_checks.json")
    args = parser.parse_args()
    results = {"device": str(jax.devices()[0].device_kind), "jax": jax.__version__,
               "command": " ".join(["python", *sys.argv])}

    def save() -> None:
        with open(args.out, "w") as f:
            json.dump(results, f, indent=1)

    if "gains" in args.parts:
        log(f"gains: {args.gain_batch} arms x {args.gain_steps} random actions")
        start = time.perf_counter()
        results["gains"] = tracking_gains(args.gain_batch, args.gain_steps)
        results["gains"]["seconds_incl_compile"] = time.perf_counter() - start
        log(json.dumps(results["gains"]))
        save()
    if "compile" in args.parts:
        log(f"compile: pieces at {args.compile_batch} arms (persistent cache off)")
        results["compile"] = {"batch": args.compile_batch, "steps": args.compile_steps}
        results["compile"].update(compile_pieces(args.compile_batch, args.compile_steps,
                                                 args.pieces))
        save()
    if "linesearch" in args.parts:
        log(f"line search: {args.ls_batch} arms x {args.ls_steps} saturated steps")
        results["linesearch"] = line_search(args.ls_batch, args.ls_steps, args.ls_lengths)
        save()
    if "ls_vs_c" in args.parts:
        log(f"ls_vs_c: {args.c_batch} arms x {args.c_steps} saturated steps against MuJoCo C")
        results["ls_vs_c"] = line_search_vs_c(args.c_batch, args.c_steps, args.ls_lengths,
                                              args.c_stride)
        save()
    if "iterations" in args.parts:
        log(f"iterations: {args.ls_batch} arms x {args.ls_steps} saturated steps")
        models = {name: model_with_solver(*setting) for name, setting
                  in solver_settings(args.iterations, args.tolerances).items()}
        results["iterations"] = settings_timing(models, "100/1e-08", args.ls_batch,
                                                args.ls_steps, counting=True)
        save()
    if "iter_vs_c" in args.parts:
        log(f"iter_vs_c: {args.c_batch} arms x {args.c_steps} saturated steps against MuJoCo C")
        results["iter_vs_c"] = iterations_vs_c(args.c_batch, args.c_steps, args.iterations,
                                               args.tolerances, args.c_stride)
        save()
    if "capacity" in args.parts:
        log(f"capacity: {args.ls_batch} arms x {args.ls_steps} steps")
        shares = [c if c == "default" else float(c) for c in args.capacities]
        pairs = [None if k == "all" else int(k) for k in args.pairs]
        results["capacity"] = capacity_timing(args.ls_batch, args.ls_steps, shares, pairs)
        save()
    if "nan" in args.parts:
        for env_id in args.envs:
            log(f"{env_id}: saturated rollout, {args.batch} arms x {args.steps} steps")
            results[env_id] = saturated_rollout(env_id, args.batch, args.steps, args.bank_size)
            log(json.dumps(results[env_id]))
            save()


if __name__ == "__main__":
    main()
