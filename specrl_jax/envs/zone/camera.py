"""The robot's camera in the Zone worlds: an analytic ray caster in JAX (runs under jit and vmap).

The original renders the robot's `vision` camera with MuJoCo's OpenGL renderer (256 x 256, all
geom groups). The scene is a few primitives, so each pixel's ray is intersected analytically:

* the floor, z = 0: a checker of 0.35 m squares in the two tones of the original's texture,
  unlit (the original's floor shows its texture colours unchanged);
* the zone discs, cylinders of half-height 0.01 (level 0 centred at z 0.02, moving levels at
  0.01): a ray inside a disc's top or bottom face passes the disc's two faces, each blended with
  alpha 0.25, so the disc colour covers 1 - 0.75^2 of what lies behind; overlapping discs are
  blended back to front by their centre's distance from the camera, as MuJoCo sorts them;
* the four walls (boxes at +-3.5 m, inner faces at +-3.45 m, z -0.05..0.55), grey 0.5 lit by the
  head light only;
* the robot's own geoms that can be in view (spheres, boxes, capsules; cylinders too), opaque,
  lit by MuJoCo's head light (ambient 0.1, diffuse 0.4 along the view direction) and the scene's
  light from straight above (diffuse 1);
* the sky, black (the original's star skybox could not be read; its reference frames are black).

The per-pixel arithmetic (`Camera._shade`) runs either as plain jnp over the whole frame, or on a
GPU inside one Pallas (Triton) kernel per world and block of pixels, reading the world's scene
from a flat table (`_TableView`); XLA alone splits the jnp version into several kernels with
float32 temporaries per pixel (2.5x slower, 9x the memory on an H100, measured when the kernel
was written).

Shading departures (no specular highlights, no floor reflections, no anti-aliasing) are listed in
`docs/fidelity.md`; `docs/vision.md` compares frames with the original's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from specrl_jax.envs.zone.mjx_import import mjx

#: Checker square, metres: a 100-texel 2 x 2 checker repeated 10 times over the 7 m floor.
CHECKER = 0.35
FLOOR_RGB = ((0.859, 0.843, 0.765), (0.949, 0.914, 0.855))
WALL_INNER = 3.45  # inner face of the wall boxes (centre 3.5, half-thickness 0.05), metres
WALL_TOP = 0.55
WALL_GREY = 0.5
ZONE_ALPHA = 0.25
ZONE_HALF_HEIGHT = 0.01
HEAD_AMBIENT, HEAD_DIFFUSE, TOP_DIFFUSE = 0.1, 0.4, 1.0

#: Zone colours of the 16 names the original accepts. The benchmark's four (green, yellow, blue,
#: magenta) are the original's; the others are the usual values of those names (not checked).
ZONE_RGB: dict[str, tuple[float, float, float]] = {
    "black": (0.0, 0.0, 0.0), "blue": (0.0, 0.0, 1.0), "green": (0.0, 1.0, 0.0),
    "cyan": (0.0, 1.0, 1.0), "red": (1.0, 0.0, 0.0), "magenta": (1.0, 0.0, 1.0),
    "yellow": (1.0, 1.0, 0.0), "white": (1.0, 1.0, 1.0), "orange": (1.0, 0.5, 0.0),
    "purple": (0.5, 0.0, 0.5), "lime": (0.5, 1.0, 0.0), "teal": (0.0, 0.5, 0.5),
    "pink": (1.0, 0.75, 0.8), "brown": (0.6, 0.3, 0.1), "navy": (0.0, 0.0, 0.5),
    "gray": (0.5, 0.5, 0.5),
}

_RED, _BLUE = (0.7412, 0.0431, 0.1843), (0.0039, 0.1529, 0.3961)
_TAN, _ORANGE = (0.8, 0.6, 0.4), (0.8, 0.5, 0.3)

#: Robot geoms drawn, with the original's colours. Geoms left out lie behind the camera in every
#: pose (every ray of the camera points to body +x for Point, -y for Car, +y for Ant; tested).
ROBOT_GEOMS: dict[str, tuple[tuple[str, tuple[float, float, float]], ...]] = {
    "Point": (("agent", _RED), ("pointarrow", _BLUE)),
    "Car": (("agent", _RED), ("front_bumper", _BLUE), ("front_connector", _BLUE), ("rear", _RED)),
    "Ant": (
        ("torso_geom", _TAN), ("aux_1_geom", _BLUE), ("left_leg_geom", _BLUE),
        ("left_ankle_geom", _ORANGE), ("aux_2_geom", _BLUE), ("right_leg_geom", _BLUE),
        ("right_ankle_geom", _TAN),
    ),
}
#: Every robot geom with its original colour (for the test that the left-out ones never show).
ALL_ROBOT_GEOMS = {
    "Car": ROBOT_GEOMS["Car"] + (("back_bumper", _BLUE), ("back_connector", _BLUE),
                                 ("left", _RED), ("right", _RED)),
    "Ant": ROBOT_GEOMS["Ant"] + (
        ("aux_3_geom", _RED), ("back_leg_geom", _RED), ("third_ankle_geom", _TAN),
        ("aux_4_geom", _RED), ("rightback_leg_geom", _RED), ("fourth_ankle_geom", _ORANGE),
    ),
}


#: Accepted `Camera(backend=...)` values.
BACKENDS = ("auto", "xla", "pallas", "pallas_interpret")
#: Pixels per Pallas program (the largest power of two up to this that divides H * W).
PALLAS_BLOCK = 512

_PRIMITIVES = (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CAPSULE,
               mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_BOX)


@dataclass(frozen=True)
class CameraMount:
    """A robot's `vision` camera in its body frame: `pos` metres, `rot` body <- camera
    (columns: camera x right, y up, z backwards; the camera looks along -z), `fovy` degrees."""

    pos: tuple[float, float, float]
    rot: tuple[tuple[float, ...], ...]
    fovy: float


def _xyaxes(x: tuple[float, ...], y: tuple[float, ...]) -> tuple[tuple[float, ...], ...]:
    x_axis = np.asarray(x, float) / np.linalg.norm(x)
    y_axis = np.asarray(y, float) - np.dot(y, x_axis) * x_axis
    y_axis /= np.linalg.norm(y_axis)
    rot = np.stack([x_axis, y_axis, np.cross(x_axis, y_axis)], axis=1)
    return tuple(map(tuple, rot))


def _euler_x(angle: float) -> tuple[tuple[float, ...], ...]:
    c, s = np.cos(angle), np.sin(angle)
    return ((1.0, 0.0, 0.0), (0.0, c, -s), (0.0, s, c))


#: The original's `vision` cameras (robot XMLs: Point/Car `xyaxes`, Ant `euler="0.94 0 0"`).
MOUNTS = {
    "Point": CameraMount((0.0, 0.0, 0.4), _xyaxes((0, -1, 0), (0.7, 0, 1)), 90.0),
    "Car": CameraMount((0.0, 0.0, 0.4), _xyaxes((-1, 0, 0), (0, -0.7, 1)), 90.0),
    "Ant": CameraMount((0.0, 0.05, 0.2), _euler_x(0.94), 100.0),
}


@struct.dataclass
class Scene:
    """What one frame depends on (one world; batch with vmap).

    Attributes:
        cam_pos: float32[3], camera position, metres.
        cam_rot: float32[3, 3], world <- camera rotation.
        zone_xy: float32[Z, 2], zone centres, metres.
        geom_pos: float32[G, 3], centres of the drawn robot geoms, metres.
        geom_rot: float32[G, 3, 3], their world <- geom rotations.
    """

    cam_pos: jax.Array
    cam_rot: jax.Array
    zone_xy: jax.Array
    geom_pos: jax.Array
    geom_rot: jax.Array


class Hit(NamedTuple):
    """What a pixel's ray meets, each `[H, W]`: `t` the first surface's distance (metres, inf
    for the sky) and `kind` its code (`Camera.SKY`, `FLOOR`, `WALL + face`, `GEOM + g`,
    `ZONE + z`)."""

    t: jax.Array
    kind: jax.Array


def _dot(a: tuple, b: tuple) -> jax.Array:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _where3(cond: jax.Array, a: tuple, b: tuple) -> tuple:
    return tuple(jnp.where(cond, x, y) for x, y in zip(a, b))


class Camera:
    """Renders a Zone world from its robot's `vision` camera.

    Args:
        mj_model: the robot's MuJoCo model (geoms are looked up by name).
        robot: "Point", "Car" or "Ant".
        zone_rgb: float32[Z, 3], each zone's colour in [0, 1].
        zone_radius: float32[Z], metres.
        zone_height: z of the zone bodies' centres, metres (0.02 at level 0, 0.01 with moving
            zones).
        size: `(H, W)` pixels.
        geoms: the robot geoms to draw as `(name, rgb)` (default `ROBOT_GEOMS[robot]`).
        backend: "auto" (a Pallas kernel on a GPU, plain XLA elsewhere), "xla", "pallas", or
            "pallas_interpret" (the kernel run by Pallas' interpreter, for tests on a CPU). The
            attribute may be changed before tracing.
    """

    SKY, FLOOR, WALL, GEOM, ZONE = 0, 1, 2, 10, 100

    def __init__(
        self,
        mj_model: mujoco.MjModel,
        robot: str,
        zone_rgb: np.ndarray,
        zone_radius: np.ndarray,
        zone_height: float,
        size: tuple[int, int],
        geoms: tuple[tuple[str, tuple[float, float, float]], ...] | None = None,
        backend: str = "auto",
    ):
        if backend not in BACKENDS:
            raise ValueError(f"unknown camera backend {backend!r}; accepted: {BACKENDS}")
        self.backend = backend
        geoms = ROBOT_GEOMS[robot] if geoms is None else geoms
        self.mount = MOUNTS[robot]
        self.size = (int(size[0]), int(size[1]))
        self.zone_rgb = np.asarray(zone_rgb, np.float32).reshape(-1, 3)
        self.zone_radius = np.asarray(zone_radius, np.float32).reshape(-1)
        self.zone_z = (zone_height - ZONE_HALF_HEIGHT, zone_height + ZONE_HALF_HEIGHT)
        self.geom_ids = np.asarray(
            [mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, name) for name, _ in geoms]
        )
        if (self.geom_ids < 0).any():
            raise ValueError(f"geoms {[n for n, _ in geoms]} are not all in the robot's model")
        self.geom_type = tuple(int(mj_model.geom_type[g]) for g in self.geom_ids)
        supported = {int(t) for t in _PRIMITIVES}
        if not set(self.geom_type) <= supported:
            raise ValueError(
                f"drawable geom types are {sorted(supported)} (sphere, capsule, cylinder, box); "
                f"got {self.geom_type}"
            )
        self.geom_size = tuple(
            tuple(float(v) for v in mj_model.geom_size[g]) for g in self.geom_ids
        )
        self.geom_rgb = tuple(tuple(rgb) for _, rgb in geoms)
        self._model = mjx.put_model(mj_model, impl="jax")
        self._data = mjx.make_data(self._model)

    # ---- the scene of one world -------------------------------------------------------
    def scene(self, qpos: jax.Array, zone_xy: jax.Array) -> Scene:
        """The scene at the robot's `qpos` ([nq]) with zones at `zone_xy` (float32[Z, 2])."""
        data = mjx.kinematics(self._model, self._data.replace(qpos=qpos))
        mount_rot = jnp.asarray(self.mount.rot, jnp.float32)
        body_pos, body_rot = data.xpos[1], data.xmat[1]
        return Scene(
            cam_pos=(body_pos + body_rot @ jnp.asarray(self.mount.pos)).astype(jnp.float32),
            cam_rot=(body_rot @ mount_rot).astype(jnp.float32),
            zone_xy=jnp.asarray(zone_xy, jnp.float32),
            geom_pos=data.geom_xpos[self.geom_ids].astype(jnp.float32),
            geom_rot=data.geom_xmat[self.geom_ids].astype(jnp.float32),
        )

    # ---- rays ----------------------------------------------------------------------------
    def _pixels(self) -> tuple[jax.Array, jax.Array]:
        """Row and column index of every pixel, float32[H, W] each."""
        return (jax.lax.broadcasted_iota(jnp.float32, self.size, 0),
                jax.lax.broadcasted_iota(jnp.float32, self.size, 1))

    def _rays(self, cam_rot, row: jax.Array, col: jax.Array) -> tuple:
        """Unit ray directions of the pixels at `row`, `col` in the world frame (3 arrays)."""
        height, width = self.size
        tan = np.tan(np.deg2rad(self.mount.fovy) / 2)
        u = ((col + 0.5) * (2.0 / width) - 1.0) * (tan * width / height)
        v = (1.0 - (row + 0.5) * (2.0 / height)) * tan
        inv = jax.lax.rsqrt(u * u + v * v + 1.0)
        cam = (u * inv, v * inv, -inv)
        return tuple(
            cam_rot[i, 0] * cam[0] + cam_rot[i, 1] * cam[1] + cam_rot[i, 2] * cam[2]
            for i in range(3)
        )

    # ---- primitives: (t [H, W] or inf, normal (3 x [H, W])) -------------------------------
    @staticmethod
    def _sphere(origin, ray, centre, radius):
        oc = tuple(origin[i] - centre[i] for i in range(3))
        b = _dot(ray, oc)
        disc = b * b - (_dot(oc, oc) - radius * radius)
        t = -b - jnp.sqrt(jnp.maximum(disc, 0.0))
        t = jnp.where((disc >= 0) & (t > 0), t, jnp.inf)
        normal = tuple((oc[i] + t * ray[i]) / radius for i in range(3))
        return t, normal

    @staticmethod
    def _box(origin, ray, centre, rot, half):
        oc = tuple(origin[i] - centre[i] for i in range(3))
        local_o = [oc[0] * rot[0, k] + oc[1] * rot[1, k] + oc[2] * rot[2, k] for k in range(3)]
        local_d = [ray[0] * rot[0, k] + ray[1] * rot[1, k] + ray[2] * rot[2, k] for k in range(3)]
        near, far, axis, sign = -jnp.inf, jnp.inf, 0, 0.0
        for k in range(3):
            d = jnp.where(jnp.abs(local_d[k]) < 1e-12, 1e-12, local_d[k])
            t1 = (-half[k] - local_o[k]) / d
            t2 = (half[k] - local_o[k]) / d
            enter = jnp.minimum(t1, t2)
            better = enter > near
            axis = jnp.where(better, k, axis)
            sign = jnp.where(better, jnp.where(d > 0, -1.0, 1.0), sign)
            near = jnp.maximum(near, enter)
            far = jnp.minimum(far, jnp.maximum(t1, t2))
        t = jnp.where((near <= far) & (near > 0), near, jnp.inf)
        normal = tuple(
            sign * jnp.where(axis == 0, rot[i, 0], jnp.where(axis == 1, rot[i, 1], rot[i, 2]))
            for i in range(3)
        )
        return t, normal

    @staticmethod
    def _capsule(origin, ray, centre, rot, radius, half_length):
        axis = (rot[0, 2], rot[1, 2], rot[2, 2])
        base = tuple(centre[i] - half_length * axis[i] for i in range(3))
        length = 2.0 * half_length
        oa = tuple(origin[i] - base[i] for i in range(3))
        along_ray, along_o = _dot(axis, ray), _dot(axis, oa)
        ray_o = _dot(ray, oa)
        a = 1.0 - along_ray * along_ray
        b = ray_o - along_o * along_ray
        c = _dot(oa, oa) - along_o * along_o - radius * radius
        disc = b * b - a * c
        t_side = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.maximum(a, 1e-12)
        y = along_o + t_side * along_ray
        side = (disc >= 0) & (a > 1e-12) & (y > 0) & (y < length) & (t_side > 0)
        # otherwise the nearer end cap (a sphere at the segment end on the hit's side)
        cap_at_end = y >= length
        oc = tuple(oa[i] - jnp.where(cap_at_end, length, 0.0) * axis[i] for i in range(3))
        b_cap = _dot(ray, oc)
        disc_cap = b_cap * b_cap - (_dot(oc, oc) - radius * radius)
        t_cap = -b_cap - jnp.sqrt(jnp.maximum(disc_cap, 0.0))
        cap = (disc >= 0) & (disc_cap >= 0) & (t_cap > 0)
        t = jnp.where(side, t_side, jnp.where(cap, t_cap, jnp.inf))
        point = tuple(oa[i] + t * ray[i] for i in range(3))
        s = jnp.clip(_dot(point, axis), 0.0, length)
        normal = tuple((point[i] - s * axis[i]) / radius for i in range(3))
        return t, normal

    @staticmethod
    def _cylinder(origin, ray, centre, rot, radius, half_height):
        oc = tuple(origin[i] - centre[i] for i in range(3))
        o = [oc[0] * rot[0, k] + oc[1] * rot[1, k] + oc[2] * rot[2, k] for k in range(3)]
        d = [ray[0] * rot[0, k] + ray[1] * rot[1, k] + ray[2] * rot[2, k] for k in range(3)]
        a = d[0] * d[0] + d[1] * d[1]
        b = o[0] * d[0] + o[1] * d[1]
        disc = b * b - a * (o[0] * o[0] + o[1] * o[1] - radius * radius)
        t_side = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.maximum(a, 1e-12)
        within = jnp.abs(o[2] + t_side * d[2]) <= half_height
        side = (disc >= 0) & (a > 1e-12) & within & (t_side > 0)
        dz = jnp.where(jnp.abs(d[2]) < 1e-12, 1e-12, d[2])
        t_cap = (jnp.where(dz > 0, -half_height, half_height) - o[2]) / dz  # the cap facing the ray
        x, y = o[0] + t_cap * d[0], o[1] + t_cap * d[1]
        cap = (x * x + y * y <= radius * radius) & (t_cap > 0)
        t = jnp.where(side, t_side, jnp.where(cap, t_cap, jnp.inf))
        local = [jnp.where(side, o[k] + t * d[k], 0.0) / radius for k in range(2)]
        local.append(jnp.where(side, 0.0, jnp.where(dz > 0, -1.0, 1.0)))
        normal = tuple(sum(rot[i, k] * local[k] for k in range(3)) for i in range(3))
        return t, normal

    def _robot(self, scene, origin, ray, forward):
        """Nearest robot geom: `(t, index, rgb)`, index -1 where none is hit."""
        t_best = jnp.full(ray[0].shape, jnp.inf)
        index = jnp.full(ray[0].shape, -1, jnp.int32)
        rgb = (jnp.zeros(ray[0].shape),) * 3
        for g, (kind, size, color) in enumerate(zip(self.geom_type, self.geom_size, self.geom_rgb)):
            centre, rot = scene.geom_pos[g], scene.geom_rot[g]
            if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                t, normal = self._sphere(origin, ray, centre, size[0])
            elif kind == mujoco.mjtGeom.mjGEOM_BOX:
                t, normal = self._box(origin, ray, centre, rot, size)
            elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
                t, normal = self._cylinder(origin, ray, centre, rot, size[0], size[1])
            else:
                t, normal = self._capsule(origin, ray, centre, rot, size[0], size[1])
            light = (
                HEAD_AMBIENT
                + HEAD_DIFFUSE * jnp.maximum(-_dot(normal, forward), 0.0)
                + TOP_DIFFUSE * jnp.maximum(normal[2], 0.0)
            )
            nearer = t < t_best
            t_best = jnp.where(nearer, t, t_best)
            index = jnp.where(nearer, g, index)
            rgb = _where3(nearer, tuple(jnp.minimum(c * light, 1.0) for c in color), rgb)
        return t_best, index, rgb

    # ---- the frame ---------------------------------------------------------------------
    def _trace(self, scene, row: jax.Array, col: jax.Array):
        """Floor, walls, sky and robot along the rays of the pixels at `row`, `col`. `scene` is
        a `Scene` or a view with the same fields that yields scalars (`_TableView`)."""
        origin = tuple(scene.cam_pos[i] for i in range(3))
        forward = tuple(-scene.cam_rot[i, 2] for i in range(3))
        ray = self._rays(scene.cam_rot, row, col)
        shape = ray[0].shape

        # floor and walls: the ray leaves the walls' inner box at t_wall
        down = ray[2] < 0
        t_floor = jnp.where(down, -origin[2] / jnp.where(down, ray[2], -1.0), jnp.inf)
        t_axis = []
        for i in range(2):
            d = jnp.where(jnp.abs(ray[i]) < 1e-12, 1e-12, ray[i])
            t_axis.append((jnp.where(d > 0, WALL_INNER, -WALL_INNER) - origin[i]) / d)
        t_wall = jnp.minimum(t_axis[0], t_axis[1])
        wall_face = jnp.where(t_axis[0] < t_axis[1], jnp.where(ray[0] > 0, 0, 1),
                              jnp.where(ray[1] > 0, 2, 3))  # east, west, north, south
        below_top = origin[2] + t_wall * ray[2] <= WALL_TOP
        on_floor = t_floor <= t_wall
        on_wall = ~on_floor & below_top
        t_scene = jnp.where(on_floor, t_floor, jnp.where(on_wall, t_wall, jnp.inf))

        # background colour: floor checker, wall grey (head light), sky black
        x = origin[0] + t_floor * ray[0]
        y = origin[1] + t_floor * ray[1]
        squares = jnp.floor(x / CHECKER) + jnp.floor(y / CHECKER)
        parity = squares - 2.0 * jnp.floor(0.5 * squares)
        face_light = [
            HEAD_AMBIENT + HEAD_DIFFUSE * jnp.maximum(sign * forward[axis], 0.0)
            for axis, sign in ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))
        ]
        wall = WALL_GREY * jnp.where(
            wall_face == 0, face_light[0],
            jnp.where(wall_face == 1, face_light[1],
                      jnp.where(wall_face == 2, face_light[2], face_light[3])),
        )
        rgb = tuple(
            jnp.where(on_floor, jnp.where(parity > 0.5, FLOOR_RGB[0][i], FLOOR_RGB[1][i]),
                      jnp.where(on_wall, wall, 0.0))
            for i in range(3)
        )
        kind = jnp.where(on_floor, self.FLOOR, jnp.where(on_wall, self.WALL + wall_face, self.SKY))

        # the robot, opaque, in front of floor and walls
        t_robot, geom, robot_rgb = self._robot(scene, origin, ray, forward)
        on_robot = t_robot < t_scene
        t_back = jnp.minimum(t_robot, t_scene)
        rgb = _where3(on_robot, robot_rgb, rgb)
        kind = jnp.where(on_robot, self.GEOM + geom, kind)
        return origin, ray, forward, t_back, rgb, kind, shape

    def _zone_planes(self, origin, ray):
        """The ray's points on the discs' bottom and top planes: ((t, x, y), (t, x, y))."""
        planes = []
        for z in self.zone_z:
            down = ray[2] < 0
            t = jnp.where(down, (z - origin[2]) / jnp.where(down, ray[2], -1.0), jnp.inf)
            planes.append((t, origin[0] + t * ray[0], origin[1] + t * ray[1]))
        return planes

    def _in_zone(self, planes, t_back, centre, radius):
        """`(top, side, t_entry)` for one disc, each [H, W]: the ray enters the disc (before
        `t_back`) through its top face, or through its side (it then leaves through the bottom
        face; the side is what the original shows as the disc's darker near rim)."""
        (t_bottom, xb, yb), (t_top, xt, yt) = planes
        r2 = radius * radius
        top = ((xt - centre[0]) ** 2 + (yt - centre[1]) ** 2 <= r2) & (t_top < t_back)
        bottom = ((xb - centre[0]) ** 2 + (yb - centre[1]) ** 2 <= r2) & (t_bottom < t_back)
        return top, bottom & ~top, jnp.where(top, t_top, t_bottom)

    def _zones_sorted(self, scene: Scene) -> tuple[jax.Array, jax.Array, jax.Array]:
        """Zone centres, colours and radii back to front by the distance of the disc centres
        from the camera (the order in which MuJoCo blends transparent geoms)."""
        gap = scene.zone_xy - scene.cam_pos[:2]
        order = jnp.argsort(-jnp.sum(gap * gap, axis=-1))
        return (scene.zone_xy[order], jnp.asarray(self.zone_rgb)[order],
                jnp.asarray(self.zone_radius)[order])

    def _shade(self, scene, zone_xy, zone_rgb, zone_radius, row, col) -> tuple:
        """RGB in [0, 1] of the pixels at `row`, `col` (3 arrays); zones sorted back to front."""
        origin, ray, forward, t_back, rgb, _, _ = self._trace(scene, row, col)
        planes = self._zone_planes(origin, ray)
        top_light = HEAD_AMBIENT + HEAD_DIFFUSE * jnp.maximum(-forward[2], 0.0) + TOP_DIFFUSE
        cover = 1.0 - (1.0 - ZONE_ALPHA) ** 2
        (_, x_bottom, y_bottom), _ = planes
        for k in range(self.zone_rgb.shape[0]):
            centre = (zone_xy[k, 0], zone_xy[k, 1])
            top, side, _ = self._in_zone(planes, t_back, centre, zone_radius[k])
            # the side's outward normal, taken where the ray leaves through the bottom face
            facing = -(forward[0] * (x_bottom - centre[0]) + forward[1] * (y_bottom - centre[1]))
            side_light = HEAD_AMBIENT + HEAD_DIFFUSE * jnp.clip(facing / zone_radius[k], 0.0, 1.0)
            light = jnp.where(top, top_light, side_light)
            rgb = tuple(
                jnp.where(top | side, c + cover * (jnp.minimum(zone_rgb[k, i] * light, 1.0) - c), c)
                for i, c in enumerate(rgb)
            )
        return tuple(jnp.floor(jnp.clip(c, 0.0, 1.0) * 255.0 + 0.5) for c in rgb)

    def render(self, scene: Scene) -> jax.Array:
        """uint8[H, W, 3]: the RGB frame of one world (batch it with `vmap`).

        With `backend` "pallas" (the default on a GPU) the frame is one fused kernel per
        world and block of pixels (`_kernel`); "xla" is the same arithmetic in plain jnp, which
        XLA splits into several kernels with float32 temporaries per pixel.
        """
        if self._pallas_block() is None:
            rgb = self._shade(scene, *self._zones_sorted(scene), *self._pixels())
            return jnp.stack(rgb, axis=-1).astype(jnp.uint8)
        return self._render_pallas(scene)

    # ---- the fused kernel ---------------------------------------------------------------
    def _pallas_block(self) -> int | None:
        """Pixels per Pallas program, or None where the XLA path renders."""
        backend = self.backend
        if backend == "auto":
            backend = "pallas" if jax.default_backend() == "gpu" else "xla"
        if backend == "xla":
            return None
        pixels = self.size[0] * self.size[1]
        return int(np.gcd(pixels, PALLAS_BLOCK))

    def _render_pallas(self, scene: Scene) -> jax.Array:
        from jax.experimental import pallas as pl
        from jax.experimental.pallas import triton

        interpret = self.backend == "pallas_interpret"

        num_geoms, num_zones = len(self.geom_type), self.zone_rgb.shape[0]
        fields = _table_fields(num_geoms, num_zones)
        zone_xy, zone_rgb, zone_radius = self._zones_sorted(scene)
        values = {"cam_pos": scene.cam_pos, "cam_rot": scene.cam_rot, "geom_pos": scene.geom_pos,
                  "geom_rot": scene.geom_rot, "zone_xy": zone_xy, "zone_rgb": zone_rgb,
                  "zone_radius": zone_radius}
        table = jnp.concatenate([jnp.ravel(values[name]).astype(jnp.float32) for name in fields])
        size = 1 << int(np.ceil(np.log2(table.shape[0])))  # Triton blocks are powers of two
        table = jnp.pad(table, (0, size - table.shape[0]))
        block, (height, width) = self._pallas_block(), self.size

        def kernel(table_ref, out_ref):
            views, offset = {}, 0
            for name, shape in fields.items():
                views[name] = _TableView(table_ref, offset, shape)
                offset += int(np.prod(shape))
            index = pl.program_id(0) * block + jax.lax.broadcasted_iota(jnp.int32, (block,), 0)
            row = (index // width).astype(jnp.float32)
            col = (index - (index // width) * width).astype(jnp.float32)
            view = Scene(cam_pos=views["cam_pos"], cam_rot=views["cam_rot"], zone_xy=None,
                         geom_pos=views["geom_pos"], geom_rot=views["geom_rot"])
            r, g, b = self._shade(view, views["zone_xy"], views["zone_rgb"],
                                  views["zone_radius"], row, col)
            packed = r.astype(jnp.int32) + 256 * g.astype(jnp.int32) + 65536 * b.astype(jnp.int32)
            out_ref[...] = packed

        packed = pl.pallas_call(
            kernel,
            out_shape=jax.ShapeDtypeStruct((height * width,), jnp.int32),
            grid=(height * width // block,),
            in_specs=[pl.BlockSpec((size,), lambda j: (0,))],
            out_specs=pl.BlockSpec((block,), lambda j: (j,)),
            interpret=interpret,
            # Triton (not Mosaic GPU): it lowers scalar table reads and batches under vmap
            compiler_params=None if interpret else triton.CompilerParams(num_warps=4, num_stages=1),
        )(table)
        rgba = jax.lax.bitcast_convert_type(packed, jnp.uint8)  # little-endian: r, g, b, 0
        return rgba[:, :3].reshape(height, width, 3)

    def first_hit(self, scene: Scene) -> Hit:
        """The first surface along each pixel's ray (geometry only, for tests and debugging)."""
        origin, ray, _, t_back, _, kind, _ = self._trace(scene, *self._pixels())
        planes = self._zone_planes(origin, ray)
        t_best = t_back
        for z in range(self.zone_rgb.shape[0]):
            top, side, t_zone = self._in_zone(planes, t_back, scene.zone_xy[z], self.zone_radius[z])
            nearer = (top | side) & (t_zone < t_best)
            t_best = jnp.where(nearer, t_zone, t_best)
            kind = jnp.where(nearer, self.ZONE + z, kind)
        return Hit(t_best, kind)

    def ray_directions(self, scene: Scene) -> jax.Array:
        """float32[H, W, 3]: each pixel's unit ray in the world frame (from `scene.cam_pos`)."""
        return jnp.stack(self._rays(scene.cam_rot, *self._pixels()), axis=-1)


class _TableView:
    """Read-only view of a flat float32 table (a Pallas ref) as the fields of a `Scene`, with
    sorted zones: `view.cam_rot[i, k]`, `view.geom_pos[g][i]`, ... give scalars."""

    def __init__(self, ref, offset: int = 0, shape: tuple[int, ...] = ()):
        self._ref, self._offset, self._shape = ref, offset, shape

    def __getitem__(self, index):
        index = index if isinstance(index, tuple) else (index,)
        offset, shape = self._offset, self._shape
        for i in index:
            stride = int(np.prod(shape[1:]))
            offset, shape = offset + int(i) * stride, shape[1:]
        return _TableView(self._ref, offset, shape) if shape else self._ref[offset]


def _table_fields(num_geoms: int, num_zones: int) -> dict[str, tuple[int, ...]]:
    return {"cam_pos": (3,), "cam_rot": (3, 3), "geom_pos": (num_geoms, 3),
            "geom_rot": (num_geoms, 3, 3), "zone_xy": (num_zones, 2), "zone_rgb": (num_zones, 3),
            "zone_radius": (num_zones,)}


def zone_height(has_moving_zones: bool) -> float:
    """z of the zone bodies' centres in the original: 0.02 at level 0, 0.01 where zones are
    mocap-welded bodies (levels 1 and 2, moving or not)."""
    return 0.01 if has_moving_zones else 0.02


__all__ = ["ALL_ROBOT_GEOMS", "BACKENDS", "Camera", "CameraMount", "Hit", "MOUNTS", "ROBOT_GEOMS",
           "Scene",
           "ZONE_RGB", "zone_height"]
