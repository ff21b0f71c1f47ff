"""Where a MuJoCo Warp physics step of the Car and the Ant spends its time, stage by stage.

MuJoCo Warp times every function it marks as a stage with CUDA events (`EventTracer`); this
script steps our robot models (`zone.models.load_model`, the default solver settings, the
Ant's capsule contacts with MuJoCo C's frame as `physics="warp"` installs them) directly in
MuJoCo Warp, `--worlds` worlds from the env's start pose under uniform random controls, the
contact buffer sized as `zone.physics.Physics` sizes it. Prints, per robot, the mean time per
physics substep of each stage (nested stages indented) and the share of the whole step, and one
JSON row per robot (`benchmarks/harness.py`), appended to `--out` if given. Needs warp-lang and
a CUDA GPU (on a CPU, Warp records no events).

    python benchmarks/lab/warp_profile.py --robots Car Ant --worlds 262144 --substeps 50
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import mujoco
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

from specrl_jax.envs.zone import contact_frame, warp_contact_frame
from specrl_jax.envs.zone.config import DEFAULT_SOLVERS
from specrl_jax.envs.zone.env import ANT_START_JOINTS
from specrl_jax.envs.zone.models import load_model, start_height
from specrl_jax.envs.zone.physics import Physics


def import_warp():
    """warp-lang, logging warnings and errors only."""
    import warp

    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)
    return warp


def _flatten(trace: dict, depth: int = 0) -> list[tuple[int, str, float]]:
    """(depth, stage, total ms) rows of an EventTracer trace, parents before children."""
    rows = []
    for name, (events, children) in trace.items():
        rows.append((depth, name, float(sum(events))))
        rows += _flatten(children, depth + 1)
    return rows


def profile(robot: str, worlds: int, substeps: int, seed: int) -> tuple[list, float]:
    """Per-stage ms per substep, and the whole step's, for `worlds` worlds of `robot`."""
    wp = import_warp()
    from mujoco.mjx.third_party import mujoco_warp as mjw
    from mujoco.mjx.third_party.mujoco_warp._src.warp_util import EventTracer

    # Warp keeps its own contact buffer: no MJX-JAX contact cap (as `ZoneEnv` builds it)
    mj_model = load_model(robot, dataclasses.replace(DEFAULT_SOLVERS[robot], max_contacts=0))
    if contact_frame.plane_capsule_pairs(mj_model) > 0:
        warp_contact_frame.install()
    mj_data = mujoco.MjData(mj_model)
    mj_data.qpos[2] = start_height(robot, mj_model)
    if robot == "Ant":  # the env's start pose before its joint noise (Car: the model's qpos0)
        mj_data.qpos[7:] = ANT_START_JOINTS
    mujoco.mj_forward(mj_model, mj_data)
    sizes = Physics(mj_model, backend="warp")  # the buffers `physics="warp"` allocates per world
    model = mjw.put_model(mj_model)
    data = mjw.put_data(mj_model, mj_data, nworld=worlds,
                        naconmax=sizes.contacts_per_world * worlds, njmax=sizes.rows_per_world)
    rng = np.random.default_rng(seed)
    for _ in range(3):  # compile, then settle into contact
        wp.copy(data.ctrl, wp.array(rng.uniform(-1, 1, (worlds, mj_model.nu)).astype(np.float32)))
        mjw.step(model, data)
    wp.synchronize()
    totals: dict[tuple[int, str], float] = {}
    order: list[tuple[int, str]] = []
    whole = 0.0
    for _ in range(substeps):
        wp.copy(data.ctrl, wp.array(rng.uniform(-1, 1, (worlds, mj_model.nu)).astype(np.float32)))
        with EventTracer() as tracer:
            start, end = wp.Event(enable_timing=True), wp.Event(enable_timing=True)
            wp.record_event(start)
            mjw.step(model, data)
            wp.record_event(end)
            wp.synchronize()
            whole += wp.get_event_elapsed_time(start, end)
            for depth, name, ms in _flatten(tracer.trace()):
                if (depth, name) not in totals:
                    order.append((depth, name))
                totals[(depth, name)] = totals.get((depth, name), 0.0) + ms
    return [(d, n, totals[(d, n)] / substeps) for d, n in order], whole / substeps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=["Car", "Ant"],
                        choices=["Point", "Car", "Ant"])
    parser.add_argument("--worlds", type=int, default=65536)
    parser.add_argument("--substeps", type=int, default=50, help="timed physics substeps")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    wp = import_warp()
    if not wp.is_cuda_available():
        parser.error("needs a CUDA GPU: MuJoCo Warp times its stages with CUDA events")
    for robot in args.robots:
        stages, whole = profile(robot, args.worlds, args.substeps, args.seed)
        env_steps = args.worlds / (10 * whole / 1e3)  # 10 substeps per env step
        title = f"{robot}: {whole:.3f} ms per substep ({env_steps:,.0f} env-steps/s of physics alone)."
        lines = [title, "", "| stage | ms per substep | share |", "|---|---|---|"]
        lines += [f"| {'&nbsp;' * 4 * d}{name} | {ms:.3f} | {ms / whole:.0%} |"
                  for d, name, ms in stages]
        print("\n".join(lines) + "\n", flush=True)
        harness.emit(harness.row(
            f"{robot}LTL0-v0 MuJoCo Warp physics substep, {args.substeps} timed substeps",
            f"{whole:.3f} ms per substep", args.worlds, stages_ms=[
                {"depth": d, "stage": name, "ms": round(ms, 4)} for d, name, ms in stages]),
            args.out)


if __name__ == "__main__":
    main()
