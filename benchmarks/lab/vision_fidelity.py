"""Our camera frames against the original's three reference frames (seed-0 resets, 256 x 256).

Renders `{Point,Car,Ant}LTL0Vision-v0` at the layouts of the original's frames
(`docs/vision_original_*.png`), classifies every pixel of both frames by colour (sky, wall, floor,
one class per zone colour, robot) and reports the intersection over union of each class. The
original's frames are anti-aliased (MuJoCo's 4 samples per pixel), so ours is rendered at
`--supersample` times the size and box-averaged down.

Prints one JSON row per robot (`benchmarks/harness.py`), appended to `--rows` if given, and
writes the frames side by side with their classes to `--out`.

    python benchmarks/lab/vision_fidelity.py   # writes docs/vision_fidelity.png
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

import specrl_jax

DOCS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "docs")
CLASSES = ("sky", "wall", "floor", "green", "yellow", "blue", "magenta", "robot")
_PALETTE = np.array(
    [[0, 0, 0], [90, 90, 90], [235, 230, 215], [0, 220, 0], [240, 220, 0], [0, 0, 255],
     [230, 0, 230], [200, 30, 30]], np.uint8,
)

# The layouts of the original's seed-0 frames (same for the three robots; metres, radians).
AGENT_XY = (0.20501671649476405, 0.9037953387641617)
AGENT_YAW = -1.1247327081051277
ZONE_XY = (  # green0, green1, yellow0, yellow1, blue0, blue1, magenta0, magenta1
    (1.137727648522392, 0.11269018703632727), (-1.6729593730282408, -1.6101957311639912),
    (-1.8711482499827297, 1.297217397636958), (1.084811328704417, 1.4430473781625948),
    (0.08520845482527961, -0.332818434036958), (0.7707616641163331, -1.7151206606458476),
    (1.9046579684309821, -1.5520252380826904), (-1.1833287894477913, -0.5119718344222399),
)
_QUAT = (-0.8459957654173009, 0.0, 0.0, 0.5331896143924743)
QPOS = {
    "Point": (*AGENT_XY, AGENT_YAW),
    "Car": (*AGENT_XY, 0.1, *_QUAT, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
    "Ant": (*AGENT_XY, 0.18, *_QUAT, -0.0762544562091512, 1.5343929626736919,
            -0.017147401097066, -1.4836258260646535, 0.03849442387400398, -1.5841166176362116,
            -0.04692210181211092, 1.5754459374882366),
}


def classify(image: np.ndarray) -> np.ndarray:
    """int[H, W]: each pixel's class (index into `CLASSES`) by simple colour rules."""
    rgb = image.astype(np.int32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    high, low = rgb.max(-1), rgb.min(-1)
    out = np.full(image.shape[:2], CLASSES.index("robot"))
    out[(high - low < 70) & (low > 140)] = CLASSES.index("floor")
    out[(g > r + 25) & (g > b + 25) & (low > 60)] = CLASSES.index("green")
    out[(np.abs(r - g) < 35) & (np.minimum(r, g) > b + 50) & (r > 150)] = CLASSES.index("yellow")
    out[(b > r + 25) & (b > g + 25) & (np.minimum(r, g) > 100)] = CLASSES.index("blue")
    out[(r > g + 25) & (b > g + 25) & (np.minimum(r, b) > 150)] = CLASSES.index("magenta")
    out[(high - low < 12) & (high < 100)] = CLASSES.index("wall")
    out[high < 12] = CLASSES.index("sky")
    return out


def iou(ours: np.ndarray, original: np.ndarray) -> dict[str, float]:
    """Intersection over union of each class present in either frame."""
    a, b = classify(ours), classify(original)
    scores = {}
    for k, name in enumerate(CLASSES):
        union = ((a == k) | (b == k)).sum()
        if union:
            scores[name] = float(((a == k) & (b == k)).sum() / union)
    return scores


def original_frame(robot: str) -> np.ndarray:
    return np.asarray(Image.open(os.path.join(DOCS, f"vision_original_{robot}.png")).convert("RGB"))


def render_reference_layout(robot: str, size: int = 256, supersample: int = 4) -> np.ndarray:
    """uint8[size, size, 3]: our frame of the original's seed-0 layout for `robot`."""
    env, _ = specrl_jax.make(f"{robot}LTL0Vision-v0", image_size=size * supersample)
    camera = env.camera
    scene = jax.jit(camera.scene)(jnp.asarray(QPOS[robot], jnp.float32), jnp.asarray(ZONE_XY))
    frame = np.asarray(jax.jit(camera.render)(scene)).astype(np.float32)
    frame = frame.reshape(size, supersample, size, supersample, 3).mean(axis=(1, 3))
    return np.round(frame).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--supersample", type=int, default=4)
    parser.add_argument("--robots", nargs="+", choices=tuple(QPOS), default=list(QPOS))
    parser.add_argument("--out", default=os.path.join(DOCS, "vision_fidelity.png"))
    parser.add_argument("--rows", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    rows, table = [], []
    for robot in args.robots:
        ours = render_reference_layout(robot, supersample=args.supersample)
        original = original_frame(robot)
        scores = iou(ours, original)
        table.append((robot, scores))
        gap = np.full((256, 4, 3), 255, np.uint8)
        rows.append(np.concatenate(
            [original, gap, ours, gap, _PALETTE[classify(original)], gap, _PALETTE[classify(ours)]],
            axis=1,
        ))
    Image.fromarray(np.concatenate(
        [np.concatenate([row, np.full((4, row.shape[1], 3), 255, np.uint8)]) for row in rows]
    )).save(args.out)
    for robot, scores in table:
        value = ", ".join(f"{name} {score:.3f}" for name, score in scores.items())
        harness.emit(harness.row(
            f"{robot}LTL0Vision-v0 frame vs the original's, IoU per pixel class "
            f"(supersample {args.supersample})", value, None, iou=scores), args.rows)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
