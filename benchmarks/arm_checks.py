"""GPU-scale checks of the arm world: no NaN over long saturated rollouts, the per-joint
tracking gains under uniform random actions at a large batch (the reference's measurement), and
where the compile time goes (`--parts compile`: each piece of the env step lowered and compiled
alone, with the persistent compilation cache off), and what MJX's line-search length costs and
changes (`--parts linesearch`).

    python benchmarks/arm_checks.py --batch 4096 --steps 1000 --out arm_checks.json
    python benchmarks/arm_checks.py --parts compile --compile-batch 4 --out arm_compile.json

Each part prints a line when it starts and as it progresses, and the JSON file is rewritten after
every part, so a run cut short by a time limit still leaves what it measured.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax.envs.arm.model import NEUTRAL_QPOS
from specrl_jax.envs.wrappers import batch as batch_env

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


def line_search(num_envs: int, num_steps: int, lengths: list[int]) -> dict:
    """The physics step with MJX's constraint solver at other line-search lengths
    (`opt.ls_iterations`, the model's 50): MJX runs every line search as a scan of that many
    iterations (no-ops after convergence, which under `vmap` still cost a full iteration), so
    the length sets much of a substep's time while results should not depend on it.

    A rollout of `num_steps` saturated random actions at `num_envs` arms with each length
    (ms per env step after compile); then one env step from every state of the 50-iteration
    rollout with each length: how many states give bit-identical joint angles and the largest
    difference (rad)."""
    import copy

    from specrl_jax.envs.arm import model as arm_model
    from specrl_jax.envs.arm.physics import Physics

    def physics(length: int) -> Physics:
        model = copy.deepcopy(arm_model.load_model())
        model.opt.ls_iterations = length
        return Physics(model, arm_model.FORCE_LIMITS)

    actions = jnp.sign(jax.random.uniform(jax.random.key(3), (num_steps, num_envs, 7),
                                          minval=-1, maxval=1))
    start_state = jax.vmap(Physics.init, in_axes=(None, 0))(
        physics(50), jnp.tile(jnp.asarray(NEUTRAL_QPOS, jnp.float32), (num_envs, 1)))
    out, visited, last = {}, [], {}
    for length in [50, *[n for n in lengths if n != 50]]:
        p = physics(length)
        step = jax.jit(jax.vmap(lambda s, a, p=p: p.step(s, s.qpos + 0.05 * a)))
        start = time.perf_counter()
        state = jax.block_until_ready(step(start_state, actions[0]))
        compile_s = time.perf_counter() - start
        state = start_state
        start = time.perf_counter()
        for t in range(num_steps):
            if length == 50:
                visited.append(state)
            state = step(state, actions[t])
        jax.block_until_ready(state)
        out[length] = {"ms_per_env_step": 1000 * (time.perf_counter() - start) / num_steps,
                       "first_call_s": compile_s}
        last[length] = step
        log(f"line search {length}: {json.dumps(out[length])}")
    states = jax.tree.map(lambda *x: jnp.concatenate(x), *visited)
    flat_actions = actions.reshape(-1, 7)
    reference = np.asarray(last[50](states, flat_actions).qpos)
    for length, row in out.items():
        if length != 50:
            diff = np.abs(np.asarray(last[length](states, flat_actions).qpos) - reference).max(1)
            row.update(states=int(diff.size), identical=int((diff == 0).sum()),
                       max_abs_dq=float(diff.max()))
            log(f"line search {length} against 50: {json.dumps(row)}")
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
    from specrl_jax.envs.zone import small_linalg

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

    def substep(data, target):  # as inside `physics.step`: written-out Cholesky factorisations
        with small_linalg.small_cholesky():
            return physics.substep(data, target)

    data = jax.jit(jax.vmap(physics.data))(phys)
    table = {
        "kinematics": lambda: (jax.vmap(physics.data), (phys,)),
        "substep": lambda: (jax.vmap(substep), (data, phys.qpos)),
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
    parser.add_argument("--gain-batch", type=int, default=256)
    parser.add_argument("--gain-steps", type=int, default=400)
    parser.add_argument("--parts", nargs="+", choices=("gains", "nan", "compile", "linesearch"),
                        default=("gains", "nan"))
    parser.add_argument("--ls-batch", type=int, default=4096)
    parser.add_argument("--ls-steps", type=int, default=20)
    parser.add_argument("--ls-lengths", type=int, nargs="+", default=[10, 5])
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
    if "nan" in args.parts:
        for env_id in ("PandaLTLReach0Joints-v0", "PandaLTLReach1Joints-v0"):
            log(f"{env_id}: saturated rollout, {args.batch} arms x {args.steps} steps")
            results[env_id] = saturated_rollout(env_id, args.batch, args.steps, args.bank_size)
            log(json.dumps(results[env_id]))
            save()


if __name__ == "__main__":
    main()
