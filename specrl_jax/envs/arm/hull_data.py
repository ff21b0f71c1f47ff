"""Writes the arm's convex-hull files from the original's collision meshes (run once, by hand).

The original (panda-gym on PyBullet) collides and measures distances with the convex hulls of
`pybullet_data/franka_panda/meshes/collision/{link0..link7,hand,finger}.obj` (Apache-2.0, shipped in
the `pybullet` wheel and source distribution). This tool takes those meshes' vertices, keeps the
hull, and writes one OBJ per mesh under `assets/hulls/` (hull vertices and outward triangles, in
the link frame, metres). Usage:

    python -m specrl_jax.envs.arm.hull_data <dir holding the collision .obj files>
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

MESHES = ("link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand", "finger")
HULL_DIR = pathlib.Path(__file__).parent / "assets" / "hulls"


def read_obj_vertices(path: pathlib.Path) -> np.ndarray:
    """float64[V, 3]: the `v` lines of an OBJ file."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.asarray(rows, np.float64)


def convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`(vertices float64[V, 3], faces int[F, 3])` of the hull, faces counter-clockwise seen from
    outside (outward normals)."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(points)
    index = {int(v): i for i, v in enumerate(hull.vertices)}
    vertices = points[hull.vertices]
    faces = np.asarray([[index[int(v)] for v in s] for s in hull.simplices])
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    flip = np.einsum("fi,fi->f", normal, hull.equations[:, :3]) < 0
    faces[flip] = faces[flip][:, ::-1]
    return vertices, faces


def write_hull(name: str, source: pathlib.Path, out_dir: pathlib.Path = HULL_DIR) -> None:
    vertices, faces = convex_hull(read_obj_vertices(source))
    lines = [
        f"# Convex hull of pybullet_data/franka_panda/meshes/collision/{name}.obj (pybullet 3.2.6,",
        "# Apache-2.0), the collision shape of the original benchmark's Panda; link frame, metres.",
        "# Written by specrl_jax.envs.arm.hull_data.",
    ]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{name}.obj").write_text("\n".join(lines) + "\n")


def main(argv: list[str]) -> None:
    if len(argv) != 1:
        raise SystemExit(__doc__)
    source = pathlib.Path(argv[0])
    for name in MESHES:
        write_hull(name, source / f"{name}.obj")


if __name__ == "__main__":
    main(sys.argv[1:])
