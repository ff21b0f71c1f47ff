"""The arm's MuJoCo model and its fixed facts (assets/panda.xml, assets/hulls/*.obj).

Link order everywhere in this package is the original's observation/proposition list
`[0..6, 8, 9, 10]` (PyBullet link indices): panda_link1 ... panda_link7, panda_hand (the 8 "arm"
links), then the left and right finger (the 2 "gripper" links).
"""

from __future__ import annotations

import functools
import pathlib

import mujoco
import numpy as np

ASSETS = pathlib.Path(__file__).parent / "assets"
MODEL_PATH = ASSETS / "panda.xml"
HULL_DIR = ASSETS / "hulls"

#: the original's `neutral_joint_values` for the 7 arm joints, rad
NEUTRAL_QPOS = np.array([0.00, 0.41, 0.00, -1.85, 0.00, 2.26, 0.79])
#: the original's motor force limits (N m; 120, not the URDF's 12, for joints 6 and 7)
FORCE_LIMITS = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 120.0, 120.0])
#: MuJoCo body names of the observed links, in the original's order; the first 8 are "arm"
LINK_BODIES = (
    "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand",
    "leftfinger", "rightfinger",
)
NUM_ARM_LINKS = 8
#: each observed link's hull (file in assets/hulls) and its pose in the link frame
#: (the right finger's collision shape is turned by pi about z)
LINK_HULLS = (
    ("link1", 0.0), ("link2", 0.0), ("link3", 0.0), ("link4", 0.0), ("link5", 0.0),
    ("link6", 0.0), ("link7", 0.0), ("hand", 0.0), ("finger", 0.0), ("finger", np.pi),
)
#: PyBullet's collision margin is not modelled: distances are to the bare hulls (docs/fidelity.md)
GRASP_SITE = "grasptarget"


@functools.cache
def load_model(table_contacts: bool = True) -> mujoco.MjModel:
    """The arm's MuJoCo model (7 hinge joints, fingers welded closed, table and floor); without
    `table_contacts` nothing collides (the contact pairs are dropped)."""
    if table_contacts:
        return mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    spec = mujoco.MjSpec.from_file(str(MODEL_PATH))
    for pair in list(spec.pairs):
        spec.delete(pair)
    return spec.compile()


def read_hull(name: str) -> tuple[np.ndarray, np.ndarray]:
    """`(vertices float64[V, 3] (m, link frame), faces int32[F, 3] (outward))` of a hull file."""
    vertices, faces = [], []
    for line in (HULL_DIR / f"{name}.obj").read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            faces.append([int(x) - 1 for x in line.split()[1:4]])
    return np.asarray(vertices), np.asarray(faces, np.int32)


def _yaw(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return points @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


@functools.cache
def link_hulls() -> tuple[np.ndarray, ...]:
    """The observed links' hull triangles in their body frames, one `float32[T_l, 3, 3]` per
    link (metres, the original's link order)."""
    return tuple(
        _yaw(vertices, angle)[faces].astype(np.float32)
        for vertices, faces, angle in ((*read_hull(name), angle) for name, angle in LINK_HULLS)
    )


def body_ids(model: mujoco.MjModel, names: tuple[str, ...] = LINK_BODIES) -> np.ndarray:
    return np.asarray([model.body(n).id for n in names], np.int32)


__all__ = [
    "FORCE_LIMITS", "LINK_BODIES", "NEUTRAL_QPOS", "NUM_ARM_LINKS", "link_hulls",
    "load_model",
    "read_hull",
]
