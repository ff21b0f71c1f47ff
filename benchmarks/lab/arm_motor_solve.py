"""The arm's motor solve (`envs/arm/physics.motor_torque`: projected Gauss-Seidel over the 7
motor and 14 limit rows) on a batch of arms, as one physics substep runs it under `vmap`.

For each `--batches` size it times the compiled solve (median of `--repeats` calls after a
warm-up) and counts the kernels XLA made of one sweep: the fusions, library calls (`dot`,
`custom-call`) and scatters in the body of the sweep loop of the optimized HLO. On a GPU every
one of them is a kernel launch per sweep, 16 sweeps per substep and 20 substeps per env step,
which at these batch sizes is what the solve costs. One JSON row per batch size
(`benchmarks/harness.py`; appended to `--out` if given).

    python benchmarks/lab/arm_motor_solve.py --batches 4608 65536
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
from specrl_jax.envs.arm.physics import motor_torque

JOINTS = 7


def inputs(batch: int) -> tuple[jax.Array, ...]:
    """Random well-conditioned mass matrices and joint states for `batch` arms."""
    keys = jax.random.split(jax.random.key(0), 5)
    a = jax.random.normal(keys[0], (batch, JOINTS, JOINTS)) * 0.3
    mass = a @ jnp.swapaxes(a, 1, 2) + 0.5 * jnp.eye(JOINTS)
    return (mass, *(jax.random.normal(k, (batch, JOINTS)) for k in keys[1:]))


def sweep_kernels(hlo: str) -> Counter:
    """Instruction kinds in the body of the optimized program's innermost loop (the sweeps)."""
    bodies = re.findall(r"body=%?([\w.\-]+)", hlo)
    if not bodies:
        raise RuntimeError("no loop in the compiled solve: was PGS_SWEEPS set to 0?")
    blocks = {m.group(1): m.group(0) for m in re.finditer(r"(?ms)^%?([\w.\-]+) [^\n]*\{\n.*?^\}", hlo)}
    kinds = Counter()
    for line in blocks[bodies[-1]].splitlines()[1:]:
        found = re.search(r"= (?:\([^=]*\)|\S+) ([a-z][\w-]*)\(", line)
        if found:
            kinds[found.group(1)] += 1
    return kinds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batches", nargs="+", type=int, default=[4608])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    force_limit = jnp.asarray(arm_model.FORCE_LIMITS, jnp.float32)
    joint_range = jnp.stack([jnp.full(JOINTS, -2.0), jnp.full(JOINTS, 2.0)], axis=1)
    solve = jax.jit(jax.vmap(lambda m, f, v, q, t: motor_torque(
        m, f, v, q, t, force_limit, 0.002, joint_range=joint_range)))
    for batch in args.batches:
        x = inputs(batch)
        compiled = solve.lower(*x).compile()
        kinds = sweep_kernels(compiled.as_text())
        launches = {k: kinds[k] for k in ("fusion", "dot", "custom-call", "scatter") if kinds[k]}
        jax.block_until_ready(compiled(*x))
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            jax.block_until_ready(compiled(*x))
            times.append(time.perf_counter() - start)
        ms = statistics.median(times) * 1e3
        value = f"{ms:.3f} ms per solve; per sweep {launches}"
        print(f"{batch:7} arms  {value}", flush=True)
        harness.emit(harness.row("Arm motor solve (16 sweeps)", value, batch, solve_ms=round(ms, 4),
                                 sweep_kernels=launches), args.out)


if __name__ == "__main__":
    main()
