"""MuJoCo C reference steps for checking the MJX physics (tests and benchmarks use them)."""

from __future__ import annotations

import mujoco
import numpy as np


def classic_rk4_step(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """One classic RK4 step (tableau A = diag(1/2, 1/2, 1), B = (1, 2, 2, 1) / 6) on MuJoCo C's
    forward dynamics, in place: the scheme of MJX 3.17 and of MuJoCo 2.3's `mj_RungeKutta`.
    MuJoCo C 4.0's own RK4 step departs from it (up to 3.5e-5 in qpos per substep on the Ant;
    docs/fidelity.md)."""
    h, weights = model.opt.timestep, np.array([1, 2, 2, 1]) / 6
    mujoco.mj_forward(model, data)
    qpos, qvel = data.qpos.copy(), data.qvel.copy()
    vels, accs = [qvel], [data.qacc.copy()]
    for stage in (0.5, 0.5, 1.0):
        data.qpos[:] = qpos
        mujoco.mj_integratePos(model, data.qpos, stage * vels[-1], h)
        data.qvel[:] = qvel + stage * h * accs[-1]
        mujoco.mj_forward(model, data)
        vels.append(data.qvel.copy())
        accs.append(data.qacc.copy())
    data.qpos[:] = qpos
    mujoco.mj_integratePos(model, data.qpos, weights @ np.array(vels), h)
    data.qvel[:] = qvel + h * (weights @ np.array(accs))


__all__ = ["classic_rk4_step"]
