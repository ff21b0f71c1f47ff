"""Camera throughput of the Zone worlds: rendering alone, env steps with auto-reset, memory per
world and the largest PPO rollout batch, for `PointLTL0Vision-v0` (or --env) at several sizes.

Cases, run by kind in `--order` (default render, rollout, step) until --budget seconds have
passed (the rest is skipped and said so):

  render   frames/s of `camera.render(camera.scene(...))` over a batch of worlds from resets; a
           jitted scan of --steps frames per world with the zones nudged every frame (so nothing
           is loop-invariant) and the frame carried (so it is written to memory each time).
  step     env-steps/s of `batch(env, B)` (AutoReset + BatchedEnv, uniformly random actions),
           one compiled scan of --steps steps carrying the observation (the frame is written
           every step, as a rollout that feeds a policy needs). The generic auto-reset renders
           the reset's frame too, so a step renders two frames. Reset modes: "exact" (a fresh
           layout by the original's sampler) and "bank" (`env.with_map_bank`, opt-in).
  rollout  a scan of 128 auto-reset steps that stores every frame (`ys`, uint8[128, B, H, W, 3]),
           as a PPO rollout stores its observations: XLA's memory analysis of the compiled call
           gives bytes per world, and the largest batch that fits is the device memory over it
           (the policy network's activations come on top; the PPO update is not included).

    python benchmarks/vision_throughput.py --out results.md
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import shlex
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import jaxlib

import specrl_jax
from specrl_jax.envs.wrappers import batch

ROLLOUT_STEPS = 128


def _timed(compiled, args: tuple, repeats: int) -> tuple[list[float], Any]:
    out = jax.block_until_ready(compiled(*args))  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - start)
    return times, out


def _memory(compiled) -> int | None:
    """Bytes the compiled call holds at its peak (arguments + outputs + temporaries - aliases)."""
    try:
        m = compiled.memory_analysis()
        return int(m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
                   - m.alias_size_in_bytes)
    except Exception:  # noqa: BLE001  (not every backend reports it)
        return None


def _env(args: argparse.Namespace, size: int, backend: str = "auto"):
    env, params = specrl_jax.make(args.env, image_size=size)
    env.camera.backend = backend
    return env, params


def render_case(args: argparse.Namespace, size: int, num: int,
                backend: str = "auto") -> dict[str, Any]:
    env, params = _env(args, size, backend)
    camera = env.camera
    _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(
        jax.random.split(jax.random.key(0), num), params
    )
    zones = jax.vmap(env.zone_positions)(state)
    scenes = jax.jit(jax.vmap(camera.scene))(state.physics.qpos, zones)

    def run(scenes, image):
        def body(image, i):
            nudged = scenes.replace(zone_xy=scenes.zone_xy + 1e-4 * i.astype(jnp.float32))
            return jax.vmap(camera.render)(nudged), None

        image, _ = jax.lax.scan(body, image, jnp.arange(args.steps))
        return image

    image = jnp.zeros((num, size, size, 3), jnp.uint8)
    start = time.perf_counter()
    compiled = jax.jit(run, donate_argnums=1).lower(scenes, image).compile()
    compile_s = time.perf_counter() - start
    out = jax.block_until_ready(compiled(scenes, image))
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(compiled(scenes, out))
        times.append(time.perf_counter() - start)
    frames = num * args.steps
    return {"case": f"render ({_backend(env)})", "size": size, "batch": num, "steps": args.steps,
            "per_s": frames / min(times), "compile_s": compile_s, "bytes": _memory(compiled)}


def _backend(env) -> str:
    return "pallas" if env.camera._pallas_block() else "xla"


def _batched(args: argparse.Namespace, size: int, num: int, mode: str, backend: str = "auto"):
    env, params = _env(args, size, backend)
    if mode == "bank":
        params = env.with_map_bank(jax.random.key(1), params, args.bank_size)
    batched = batch(env, num)
    obs, state = jax.jit(batched.reset)(jax.random.key(2), params)
    return batched, params, obs, state


def step_case(args: argparse.Namespace, size: int, num: int, mode: str,
              backend: str = "auto") -> dict[str, Any]:
    batched, params, obs, state = _batched(args, size, num, mode, backend)

    def run(key, state, obs):
        def body(carry, _):
            key, state, obs, total = carry
            key, key_action, key_step = jax.random.split(key, 3)
            action = batched.sample_actions(key_action)
            obs, state, reward, terminated, truncated, info = batched.step(
                key_step, state, action, params
            )
            total = (total + jnp.sum(reward) + jnp.sum(terminated | truncated)
                     + jnp.sum(info["propositions"]) + jnp.sum(obs["ap"][:, 0, 0])
                     + jnp.sum(obs["image"][:, -1, :, 0], dtype=jnp.float32))
            return (key, state, obs, total), None

        (_, state, obs, total), _ = jax.lax.scan(
            body, (key, state, obs, jnp.float32(0)), None, args.steps
        )
        return state, obs, total

    key = jax.random.key(3)
    start = time.perf_counter()
    compiled = jax.jit(run, donate_argnums=(1, 2)).lower(key, state, obs).compile()
    compile_s = time.perf_counter() - start
    state, obs, _ = jax.block_until_ready(compiled(key, state, obs))
    times = []
    for repeat in range(args.repeats):
        start = time.perf_counter()
        state, obs, _ = jax.block_until_ready(compiled(jax.random.fold_in(key, repeat), state, obs))
        times.append(time.perf_counter() - start)
    return {"case": f"step ({mode}, {_backend(batched.env.env)})", "size": size, "batch": num,
            "steps": args.steps,
            "per_s": num * args.steps / min(times), "compile_s": compile_s,
            "bytes": _memory(compiled)}


def rollout_case(args: argparse.Namespace, size: int, num: int,
                 backend: str = "auto") -> dict[str, Any]:
    batched, params, obs, state = _batched(args, size, num, "exact", backend)

    def run(key, state):
        def body(carry, _):
            key, state = carry
            key, key_action, key_step = jax.random.split(key, 3)
            action = batched.sample_actions(key_action)
            obs, state, *_ = batched.step(key_step, state, action, params)
            return (key, state), obs["image"]

        (_, state), frames = jax.lax.scan(body, (key, state), None, ROLLOUT_STEPS)
        return state, frames

    key = jax.random.key(4)
    start = time.perf_counter()
    compiled = jax.jit(run, donate_argnums=1).lower(key, state).compile()
    compile_s = time.perf_counter() - start
    held = _memory(compiled)
    start = time.perf_counter()
    state, frames = jax.block_until_ready(compiled(key, state))
    run_s = time.perf_counter() - start
    del frames
    limit = (jax.devices()[0].memory_stats() or {}).get("bytes_limit")
    per_world = held / num if held else None
    largest = int(0.95 * limit / per_world) if (limit and per_world) else None
    return {"case": f"rollout {ROLLOUT_STEPS} ({_backend(batched.env.env)})", "size": size,
            "batch": num, "steps": ROLLOUT_STEPS,
            "per_s": num * ROLLOUT_STEPS / run_s, "compile_s": compile_s, "bytes": held,
            "largest_batch": largest, "device_bytes": limit}


def _versions() -> str:
    from importlib.metadata import version

    return (f"jax {jax.__version__}, jaxlib {jaxlib.__version__}, mujoco {version('mujoco')}, "
            f"mujoco-mjx {version('mujoco-mjx')}, specrl_jax {specrl_jax.__version__}, "
            f"Python {platform.python_version()}")


def _row(r: dict[str, Any]) -> str:
    per_world = f"{r['bytes'] / r['batch'] / 2**20:.2f}" if r.get("bytes") else "-"
    largest = f"{r['largest_batch']:,}" if r.get("largest_batch") else "-"
    unit = "frames/s" if r["case"].startswith("render") else "env-steps/s"
    return (f"| {r['case']} | {r['size']}x{r['size']} | {r['batch']:,} | {r['steps']} | "
            f"{r['per_s']:,.0f} {unit} | {r['compile_s']:.1f} | {per_world} | {largest} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="PointLTL0Vision-v0")
    parser.add_argument("--render", nargs="*", default=["64:262144", "256:32768"],
                        help="size:batch[:backend] for the render-alone case "
                        "(backend auto, xla, pallas)")
    parser.add_argument("--step", nargs="*", default=["64:262144:exact", "256:32768:exact",
                                                     "64:262144:bank", "256:32768:bank"],
                        help="size:batch:reset[:backend] for the env-step case")
    parser.add_argument("--rollout", nargs="*", default=["64:8192", "256:1024"],
                        help="size:batch[:backend] for the 128-step rollout memory case")
    parser.add_argument("--order", nargs=3, default=["render", "rollout", "step"],
                        help="order of the case kinds")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--bank-size", type=int, default=65536)
    parser.add_argument("--budget", type=float, default=1e9,
                        help="seconds; later cases are skipped")
    parser.add_argument("--out", default=None, help="markdown file to append the table to")
    args = parser.parse_args()

    def parse(text: str, ints: int) -> tuple:
        parts = text.split(":")
        return tuple(int(p) for p in parts[:ints]) + tuple(parts[ints:])

    cases = ([(render_case, parse(x, 2)) for x in args.render]
             + [(step_case, parse(x, 2)) for x in args.step]
             + [(rollout_case, parse(x, 2)) for x in args.rollout])
    order = {name: i for i, name in enumerate(args.order)}
    cases.sort(key=lambda case: order[case[0].__name__.split("_")[0]])
    device = jax.devices()[0]
    header = [
        f"Device: {device.device_kind} ({device.platform}). Versions: {_versions()}.",
        f"Date: {datetime.date.today().isoformat()}. "
        f"Command: `{shlex.join(['python', *sys.argv])}`",
        "",
        "| case | image | batch | steps/call | throughput (best) | compile s | MiB per world "
        "| largest batch |",
        "|---|---|---|---|---|---|---|---|",
    ]
    print("\n".join(header), flush=True)
    lines, start = list(header), time.perf_counter()
    for fn, case_args in cases:
        if time.perf_counter() - start > args.budget:
            line = f"skipped (budget): {fn.__name__}{case_args}"
        else:
            try:
                result = fn(args, *case_args)
                line = _row(result)
                print(json.dumps(result), file=sys.stderr, flush=True)
            except Exception as err:  # noqa: BLE001  (record it and go on with the next case)
                first = str(err).strip().splitlines()[0][:300] if str(err).strip() else ""
                kind = "out of memory" if "RESOURCE_EXHAUSTED" in str(err) else type(err).__name__
                line = f"{kind}: {fn.__name__}{case_args}: {first}"
        print(line, flush=True)
        lines.append(line)
        if args.out:
            with open(args.out, "w") as f:
                f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
