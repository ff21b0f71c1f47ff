"""The arm's motor solve (`envs/arm/physics.motor_torque`: projected Gauss-Seidel over the 7
motor and 14 limit rows) on a batch of arms, as one physics substep runs it under `vmap`.

For each `--solves` way of running it (`motor_torque`'s `solve`: "xla" jnp sweeps, "pallas"
one kernel per arm, GPU only) and `--batches` size it times the compiled solve (median of
`--repeats` calls after a warm-up) and counts the kernels XLA made: the fusions, library calls
(`dot`, `custom-call`, a Pallas kernel among them) and scatters of the optimized program, apart
for the body of the sweep loop, which runs 16 times. On a GPU each is a kernel launch, and
the solve runs every substep (20 per env step), which at these batch sizes is what it costs.
One JSON row per case (`benchmarks/harness.py`; appended to `--out` if given).

    python benchmarks/lab/arm_motor_solve.py --batches 4608 65536 --solves xla pallas
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import sys
import time
from collections import Counter

import jax
import jax.numpy as jnp

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.config import MOTOR_SOLVES
from specrl_jax.envs.arm.physics import motor_torque

JOINTS = 7


def inputs(batch: int) -> tuple[jax.Array, ...]:
    """Random well-conditioned mass matrices and joint states for `batch` arms."""
    keys = jax.random.split(jax.random.key(0), 5)
    a = jax.random.normal(keys[0], (batch, JOINTS, JOINTS)) * 0.3
    mass = a @ jnp.swapaxes(a, 1, 2) + 0.5 * jnp.eye(JOINTS)
    return (mass, *(jax.random.normal(k, (batch, JOINTS)) for k in keys[1:]))


KERNELS = ("fusion", "dot", "custom-call", "scatter")


def kernels(hlo: str) -> dict[str, dict[str, int]]:
    """Kernel-launching instructions of the optimized program: in its entry computation, and in
    the body of its loop (the sweeps) where it has one."""
    blocks = {m.group(1): m.group(0) for m in re.finditer(r"(?ms)^(?:ENTRY )?%?([\w.\-]+) [^\n]*\{\n.*?^\}", hlo)}
    entry = next(name for name, block in blocks.items() if block.startswith("ENTRY"))
    parts = {"entry": entry}
    bodies = re.findall(r"body=%?([\w.\-]+)", hlo)
    if bodies:
        parts["sweep"] = bodies[-1]
    counts = {}
    for part, name in parts.items():
        kinds = Counter()
        for line in blocks[name].splitlines()[1:]:
            found = re.search(r"= (?:\([^=]*\)|\S+) ([a-z][\w-]*)\(", line)
            if found and found.group(1) in KERNELS:
                kinds[found.group(1)] += 1
        counts[part] = dict(kinds)
    return counts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batches", nargs="+", type=int, default=[4608])
    parser.add_argument("--solves", nargs="+", choices=MOTOR_SOLVES, default=["xla"])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    force_limit = jnp.asarray(arm_model.FORCE_LIMITS, jnp.float32)
    joint_range = jnp.stack([jnp.full(JOINTS, -2.0), jnp.full(JOINTS, 2.0)], axis=1)
    for how, batch in ((how, batch) for how in args.solves for batch in args.batches):
        solve = jax.jit(jax.vmap(lambda m, f, v, q, t, how=how: motor_torque(
            m, f, v, q, t, force_limit, 0.002, joint_range=joint_range, solve=how)))
        x = inputs(batch)
        compiled = solve.lower(*x).compile()
        launches = kernels(compiled.as_text())
        jax.block_until_ready(compiled(*x))
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            jax.block_until_ready(compiled(*x))
            times.append(time.perf_counter() - start)
        ms = statistics.median(times) * 1e3
        value = f"{ms:.3f} ms per solve; kernels {launches}"
        print(f"{how:16} {batch:7} arms  {value}", flush=True)
        harness.emit(harness.row(f"Arm motor solve (16 sweeps), {how}", value, batch,
                                 solve=how, solve_ms=round(ms, 4), kernels=launches), args.out)


if __name__ == "__main__":
    main()
