"""The original's moving zones in MuJoCo C, for checking `motion.py` (tests and benchmarks).

Builds the robot's model plus, per zone, the original's free zone body at its layout centre,
a mocap body at the origin and a weld between them (solref 0.02 1.5, no relpose, so the weld
keeps the initial offset), and steps it as the original does: before every substep each moving
zone's mocap goes to `travel * (sin a, cos a, 0.001 / travel)`, `a = angular_speed * t *
direction + phase`, t = `data.time`; then `mj_step` (the classic RK4 of MuJoCo 2.3 for the Ant,
`c_reference.classic_rk4_step`); after the 10 substeps of an env step one `mj_forward`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from specrl_jax.envs.zone.c_reference import classic_rk4_step
from specrl_jax.envs.zone.models import Solver, robot_xml
from specrl_jax.envs.zone.motion import ORIGINAL_INTEGRATOR, WELD_SOLREF


def _yaw_quat(yaw: float) -> str:
    return f"{np.cos(yaw / 2)} 0 0 {np.sin(yaw / 2)}"


def weld_world(robot: str, zone_xy: np.ndarray, zone_yaw: np.ndarray) -> mujoco.MjModel:
    """The robot's model (MuJoCo's default solver) with the original's welded zones added."""
    objs, mocaps, welds = [], [], []
    solref = f"{WELD_SOLREF[0]} {WELD_SOLREF[1]}"
    geom = 'type="cylinder" size="0.4 0.01" contype="0" conaffinity="0"'
    rows = np.c_[np.asarray(zone_xy, np.float64), np.asarray(zone_yaw, np.float64)].tolist()
    for i, (x, y, yaw) in enumerate(rows):
        quat = _yaw_quat(yaw)
        objs.append(
            f'<body name="zone{i}obj" pos="{x!r} {y!r} 0.01" quat="{quat}">'
            f'<freejoint name="zone{i}obj"/><geom {geom} density="0.001"/></body>'
        )
        mocaps.append(
            f'<body name="zone{i}mocap" quat="{quat}" mocap="true">'
            f'<geom {geom} pos="{x!r} {y!r} 0.01"/></body>'
        )
        welds.append(f'<weld body1="zone{i}mocap" body2="zone{i}obj" solref="{solref}"/>')
    xml = robot_xml(robot, Solver())
    xml = xml.replace("</worldbody>", "".join(objs + mocaps) + "</worldbody>")
    xml = xml.replace("</mujoco>", "<equality>" + "".join(welds) + "</equality></mujoco>")
    return mujoco.MjModel.from_xml_string(xml)


def original_zone_trajectory(
    robot: str,
    zone_xy: np.ndarray,
    direction: np.ndarray,
    phase: np.ndarray,
    num_steps: int,
    zone_yaw: np.ndarray | None = None,
    travel: float = 0.3,
    angular_speed: float = 2.0,
    substeps: int = 10,
) -> np.ndarray:
    """float64[num_steps + 1, Z, 3]: zone body positions (metres) at the reset and after each
    env step of the original's moving zones; zones with direction 0 keep their mocap at the
    origin (welded but static, like level 1's second zone of each colour)."""
    zone_xy, direction, phase = (np.asarray(a, np.float64) for a in (zone_xy, direction, phase))
    zone_yaw = np.zeros(len(zone_xy)) if zone_yaw is None else np.asarray(zone_yaw)
    model = weld_world(robot, zone_xy, zone_yaw)
    data = mujoco.MjData(model)
    bodies = [model.body(f"zone{i}obj").id for i in range(len(zone_xy))]
    mocap = [model.body_mocapid[model.body(f"zone{i}mocap").id] for i in range(len(zone_xy))]
    moving = direction != 0
    rk4 = ORIGINAL_INTEGRATOR[robot] == "rk4"
    mujoco.mj_forward(model, data)
    out = [data.xpos[bodies].copy()]
    for _ in range(num_steps):
        for _ in range(substeps):
            angle = angular_speed * data.time * direction + phase
            command = np.stack(
                [travel * np.sin(angle), travel * np.cos(angle), np.full_like(angle, 0.001)], 1
            )
            data.mocap_pos[np.asarray(mocap)[moving]] = command[moving]
            if rk4:
                classic_rk4_step(model, data)
                data.time += model.opt.timestep
            else:
                mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        out.append(data.xpos[bodies].copy())
    return np.stack(out)


__all__ = ["original_zone_trajectory", "weld_world"]
