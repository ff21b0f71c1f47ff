"""A settled Ant contact state shared by the MJX-JAX and MuJoCo Warp contact-frame tests."""

import mujoco
import numpy as np


def settled_ant(model: mujoco.MjModel) -> mujoco.MjData:
    """MuJoCo C's data after 100 substeps from `qpos0` at zero control, then random controls
    (seed 0) and a forward pass: the Ant on its 4 foot tips, capsules ~10 degrees from the
    floor normal."""
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    for _ in range(100):
        mujoco.mj_step(model, data)
    data.ctrl[:] = np.random.default_rng(0).uniform(-1, 1, model.nu)
    mujoco.mj_forward(model, data)
    assert data.ncon == 4
    return data
