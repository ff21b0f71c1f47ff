"""Zone camera observations: ray geometry against MuJoCo C's ray caster, zone colours and
blending order, the robot in frame, moving zones, determinism, shapes, the Gymnasium bridge and
the original's reference frame (small images, except the 256 x 256 fidelity check)."""

from __future__ import annotations

import importlib.util
import os
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax
import specrl_jax.gym  # noqa: F401  (registers the IDs with Gymnasium)
from specrl_jax.envs.zone import ZoneConfig
from specrl_jax.envs.zone.camera import (
    ALL_ROBOT_GEOMS,
    MOUNTS,
    ROBOT_GEOMS,
    ZONE_RGB,
    Camera,
    zone_height,
)
from specrl_jax.envs.zone.models import load_model, robot_xml

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
SIZE = 32
COVER = 1.0 - 0.75**2  # a disc's two faces at alpha 0.25


def _fidelity():
    spec = importlib.util.spec_from_file_location(
        "vision_fidelity", os.path.join(ROOT, "benchmarks", "lab", "vision_fidelity.py")
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


FIDELITY = _fidelity()
COLORS = [c for c in ("green", "yellow", "blue", "magenta") for _ in range(2)]


def _camera(robot, size=SIZE, zones=COLORS, radius=0.4, geoms=None, moving=False):
    return Camera(
        load_model(robot), robot, np.asarray([ZONE_RGB[c] for c in zones]),
        np.full(len(zones), radius), zone_height(moving), (size, size), geoms,
    )


def _point_qpos(x=0.0, y=0.0, yaw=0.0):
    return jnp.asarray([x, y, yaw], jnp.float32)


# ---- geometry: every pixel's first surface against MuJoCo C (mj_ray) on the same scene ----------


def _mujoco_scene(robot: str, zone_xy: np.ndarray, z_centre: float) -> mujoco.MjModel:
    """The robot's model plus the zone cylinders and the four wall boxes of the original."""
    zones = "".join(
        f'<geom name="zone{i}" type="cylinder" size="0.4 0.01" pos="{x} {y} {z_centre}" '
        'contype="0" conaffinity="0"/>'
        for i, (x, y) in enumerate(zone_xy)
    )
    walls = "".join(
        f'<geom name="wall{face}" type="box" size="{sx} {sy} 0.3" pos="{x} {y} 0.25" '
        'contype="0" conaffinity="0"/>'
        for face, (x, y, sx, sy) in enumerate(
            [(3.5, 0, 0.05, 3.5), (-3.5, 0, 0.05, 3.5), (0, 3.5, 3.5, 0.05), (0, -3.5, 3.5, 0.05)]
        )
    )
    xml = robot_xml(robot).replace("</worldbody>", zones + walls + "</worldbody>", 1)
    return mujoco.MjModel.from_xml_string(xml)


@pytest.mark.parametrize("robot", ["Point", "Car", "Ant"])
def test_first_surface_of_every_ray_matches_mujoco_c(robot):
    camera = _camera(robot)
    qpos = np.asarray(FIDELITY.QPOS[robot], np.float32)
    zone_xy = np.asarray(FIDELITY.ZONE_XY, np.float32)
    scene = jax.jit(camera.scene)(jnp.asarray(qpos), jnp.asarray(zone_xy))
    hit = jax.jit(camera.first_hit)(scene)
    rays = np.asarray(jax.jit(camera.ray_directions)(scene), np.float64)
    kind, t = np.asarray(hit.kind), np.asarray(hit.t)

    model = _mujoco_scene(robot, zone_xy, zone_height(False))
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    names = [model.geom(g).name for g in range(model.ngeom)]
    drawn = [name for name, _ in ROBOT_GEOMS[robot]]
    ref_kind, ref_t = np.zeros_like(kind), np.full(t.shape, np.inf)
    geom_id = np.zeros(1, np.int32)
    origin = np.asarray(scene.cam_pos, np.float64)
    for row in range(SIZE):
        for col in range(SIZE):
            dist = mujoco.mj_ray(model, data, origin, rays[row, col], None, 1, -1, geom_id)
            if dist < 0:
                continue
            name = names[geom_id[0]]
            ref_t[row, col] = dist
            ref_kind[row, col] = (
                Camera.FLOOR if name == "floor"
                else Camera.ZONE + int(name[4:]) if name.startswith("zone")
                else Camera.WALL + int(name[4:]) if name.startswith("wall")
                else Camera.GEOM + drawn.index(name)
            )
    agree = kind == ref_kind
    assert agree.mean() >= 0.99, np.argwhere(~agree)
    both = agree & np.isfinite(ref_t)
    # a zone entered through its 2 cm high side: ours takes the bottom face (a few rim pixels)
    close = np.zeros(t.shape, bool)
    close[both] = np.abs(t[both] - ref_t[both]) <= 1e-4 * ref_t[both]
    assert close[both].mean() >= 0.99
    assert np.all(close[both & (kind < Camera.ZONE)])
    # the frame shows each kind of surface: floor, walls, sky, zones, the robot
    assert {Camera.SKY, Camera.FLOOR} <= set(kind.ravel().tolist())
    assert (kind >= Camera.ZONE).any() and ((kind >= Camera.GEOM) & (kind < Camera.ZONE)).any()
    assert ((kind >= Camera.WALL) & (kind < Camera.WALL + 4)).any()


# ---- colours, blending order, occlusion -----------------------------------------------------


@jax.jit(static_argnums=0)
def _frame(camera, qpos, zone_xy):
    scene = camera.scene(qpos, jnp.asarray(zone_xy, jnp.float32))
    return camera.render(scene), camera.first_hit(scene)


def _render(camera, qpos, zone_xy):
    """`(float64[H, W, 3] image, Hit)` of one world."""
    image, hit = _frame(camera, qpos, zone_xy)
    return np.asarray(image, np.float64), hit


def test_zone_colour_blending_order_and_robot_occlusion():
    # Point at the origin looking along +x; its central ray meets the floor 0.714 m ahead.
    far = [[9.0, 9.0]]  # out of sight
    render = _render
    cameras = {zones: _camera("Point", zones=zones) for zones in (("green",), ("green", "blue"))}
    qpos = _point_qpos()
    bare, _ = render(cameras[("green",)], qpos, far)
    one, hit = render(cameras[("green",)], qpos, [[0.714, 0.0]])
    centre = (SIZE // 2, SIZE // 2)
    assert int(hit.kind[centre]) == Camera.ZONE
    expected = (1 - COVER) * bare[centre] + COVER * 255 * np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(one[centre], expected, atol=1.0)

    # Two overlapping discs: the one whose centre is nearer the camera is blended last (on top).
    two, _ = render(cameras[("green", "blue")], qpos, [[0.65, 0.0], [0.80, 0.0]])
    green, blue = 255 * np.array([0.0, 1.0, 0.0]), 255 * np.array([0.0, 0.0, 1.0])
    blue_then_green = (1 - COVER) * ((1 - COVER) * bare[centre] + COVER * blue) + COVER * green
    green_then_blue = (1 - COVER) * ((1 - COVER) * bare[centre] + COVER * green) + COVER * blue
    np.testing.assert_allclose(two[centre], blue_then_green, atol=1.5)
    assert np.abs(two[centre] - green_then_blue).max() > 30
    swapped, _ = render(cameras[("green", "blue")], qpos, [[0.80, 0.0], [0.65, 0.0]])
    np.testing.assert_allclose(swapped[centre], green_then_blue, atol=1.5)

    # A disc under the robot tints the floor around it but not the robot's own body.
    under, under_hit = render(cameras[("green",)], qpos, [[0.3, 0.0]])
    robot = (np.asarray(under_hit.kind) >= Camera.GEOM) & (np.asarray(under_hit.kind) < Camera.ZONE)
    assert robot.sum() > 20
    np.testing.assert_array_equal(under[robot], bare[robot])
    tinted = np.asarray(under_hit.kind) == Camera.ZONE
    assert tinted.sum() > 50 and (under[tinted][:, 0] < bare[tinted][:, 0] - 50).all()


def test_robot_body_at_the_bottom_of_the_frame():
    camera = _camera("Point")
    image, hit = _render(camera, _point_qpos(1.0, -0.5, 2.0), [[9.0, 9.0]] * 8)
    kind = np.asarray(hit.kind)
    # the red sphere at the bottom centre, the blue arrow box above it; sky at the top
    assert kind[-1, SIZE // 2] == Camera.GEOM + 0 and kind[-6, SIZE // 2] == Camera.GEOM + 1
    red, blue = image[-1, SIZE // 2], image[-6, SIZE // 2]
    assert red[0] > 2 * max(red[1], red[2]) and blue[2] > 2 * max(blue[0], blue[1])
    assert (kind[0] == Camera.SKY).all() and (image[0] == 0).all()
    robot_rows = np.flatnonzero(((kind >= Camera.GEOM) & (kind < Camera.ZONE)).any(axis=1))
    assert robot_rows.min() > SIZE * 0.6 and robot_rows.max() == SIZE - 1


@pytest.mark.parametrize("robot", ["Car", "Ant"])
def test_geoms_left_out_never_show(robot):
    full = _camera(robot, geoms=ALL_ROBOT_GEOMS[robot])
    drawn = _camera(robot)
    model = load_model(robot)
    rng = np.random.default_rng(0)
    render = lambda camera, qpos: _render(camera, qpos, [[9.0, 9.0]] * 8)  # noqa: E731
    left_out = ~np.isin(full.geom_ids, drawn.geom_ids)
    assert left_out.any()
    for _ in range(3):
        qpos = np.asarray(FIDELITY.QPOS[robot], np.float64)
        tilt = rng.uniform(-0.3, 0.3, 2)  # roll and pitch about the original's yaw
        quat = np.zeros(4)
        mujoco.mju_euler2Quat(quat, np.array([tilt[0], tilt[1], FIDELITY.AGENT_YAW]), "xyz")
        qpos[3:7] = quat
        if robot == "Ant":  # joints anywhere in their ranges
            low, high = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
            qpos[7:] = rng.uniform(low, high)
        qpos = jnp.asarray(qpos, jnp.float32)
        (image_full, hit), (image, _) = render(full, qpos), render(drawn, qpos)
        geom = np.asarray(hit.kind) - Camera.GEOM  # the full camera's first surface per pixel
        shown = geom[(geom >= 0) & (geom < len(full.geom_ids))]
        assert not left_out[shown].any()  # no ray meets a left-out geom first
        # the same frame; the two programs may round one silhouette-edge pixel differently
        differ = (image_full != image).any(-1)
        assert differ.sum() <= 2, np.argwhere(differ)


@pytest.mark.parametrize("robot", ["Point", "Ant"])
def test_fused_kernel_renders_the_same_frames(robot):
    # the Pallas kernel (the GPU default) run by Pallas' interpreter, against the plain XLA path
    qpos = jnp.asarray(FIDELITY.QPOS[robot], jnp.float32)
    zones = jnp.asarray(FIDELITY.ZONE_XY, jnp.float32)
    qpos, zones = jnp.stack([qpos, qpos.at[1].add(-0.4)]), jnp.stack([zones, zones[::-1]])
    frames = {}
    for backend in ("xla", "pallas_interpret"):
        camera = Camera(load_model(robot), robot, np.asarray([ZONE_RGB[c] for c in COLORS]),
                        np.full(8, 0.4), zone_height(False), (SIZE, SIZE), backend=backend)
        render = jax.jit(jax.vmap(lambda q, z, camera=camera: camera.render(camera.scene(q, z))))
        frames[backend] = np.asarray(render(qpos, zones))
    assert frames["xla"].dtype == np.uint8 and frames["xla"].shape == (2, SIZE, SIZE, 3)
    assert not np.array_equal(frames["xla"][0], frames["xla"][1])
    # identical at XLA's default optimisation level; at the suite's level 0 (tests/conftest.py)
    # the two programs round differently at one silhouette-edge pixel per Ant frame (2 of 1,024)
    differ = (frames["pallas_interpret"] != frames["xla"]).any(-1)  # bool[2, SIZE, SIZE]
    assert differ.sum(axis=(1, 2)).max() <= 2, np.argwhere(differ)


# ---- the env: moving zones, determinism, shapes ---------------------------------------------


@pytest.fixture(scope="module")
def moving_world():
    env, params = specrl_jax.make("PointLTL1Vision-v0", image_size=SIZE)
    return env, params, jax.jit(env.reset_to), jax.jit(env.step), jax.jit(env.zone_positions)


def _reference_layout(env):
    """The original's seed-0 layout as a `reset_to` layout of a Point world."""
    return dict(
        agent_xy=jnp.asarray(FIDELITY.AGENT_XY), agent_yaw=jnp.asarray(FIDELITY.AGENT_YAW),
        zone_xy=jnp.asarray(FIDELITY.ZONE_XY), zone_color=jnp.asarray(env.zone_color),
        zone_radius=jnp.asarray(env.zone_radius), zone_direction=jnp.zeros(8),
        zone_phase=jnp.zeros(8),
    )


def _project(point: np.ndarray, cam_pos: np.ndarray, cam_rot: np.ndarray,
             fovy: float) -> np.ndarray:
    """Pinhole projection of a world point to (row, col) pixel coordinates (numpy)."""
    v = cam_rot.T @ (point - cam_pos)
    tan = np.tan(np.deg2rad(fovy) / 2)
    col = (v[0] / -v[2] / tan + 1) / 2 * SIZE
    row = (1 - v[1] / -v[2] / tan) / 2 * SIZE
    return np.array([row, col])


def test_moving_zone_moves_in_the_image(moving_world):
    env, params, reset_to, step, zone_positions = moving_world
    far = [[-2.2, 2.2], [-2.2, -2.2], [2.2, -2.2], [-2.2, 0.0], [0.0, -2.2], [0.0, 2.2],
           [-1.0, -2.2]]
    # the moving green zone (zone 0) 0.9 m ahead of the Point, the others static, behind or aside
    layout = dict(
        agent_xy=jnp.zeros(2), agent_yaw=jnp.array(0.0), zone_xy=jnp.asarray([[0.9, 0.0], *far]),
        zone_color=jnp.asarray(env.zone_color), zone_radius=jnp.asarray(env.zone_radius),
        zone_direction=jnp.asarray([1.0] + [0.0] * 7),
        zone_phase=jnp.asarray([np.pi / 2] + [0.0] * 7),
    )
    obs, state = reset_to(jax.random.key(0), layout, params)
    mount = MOUNTS["Point"]
    cam_pos, cam_rot = np.array([0.0, 0.0, 0.5]), np.asarray(mount.rot)
    green = FIDELITY.CLASSES.index("green")
    centroids, projected = [], []
    for _ in range(3):
        mask = FIDELITY.classify(np.asarray(obs["image"])) == green
        assert mask.sum() > 10
        centroids.append(np.argwhere(mask).mean(axis=0))
        centre = np.append(np.asarray(zone_positions(state))[0], 0.02)
        projected.append(_project(centre, cam_pos, cam_rot, mount.fovy))
        for _ in range(25):
            obs, state, *_ = step(jax.random.key(1), state, jnp.zeros(2), params)
    shift, expected = np.diff(centroids, axis=0), np.diff(projected, axis=0)
    assert (np.linalg.norm(expected, axis=1) > 1.0).all()  # it moved by more than a pixel
    for got, want in zip(shift, expected):
        cosine = got @ want / np.linalg.norm(got) / np.linalg.norm(want)
        assert cosine > 0.9 and 0.5 < np.linalg.norm(got) / np.linalg.norm(want) < 2.0


def test_frames_are_deterministic_and_batch_as_single_worlds(moving_world):
    env, params, reset_to, *_ = moving_world
    layouts = [_reference_layout(env), dict(_reference_layout(env), agent_yaw=jnp.asarray(0.3))]
    obs = [reset_to(jax.random.key(0), layout, params)[0]["image"] for layout in layouts]
    again = reset_to(jax.random.key(5), layouts[0], params)[0]["image"]
    np.testing.assert_array_equal(obs[0], again)
    assert not np.array_equal(obs[0], obs[1])  # another pose, another frame
    # a vmapped batch of scenes renders each world as it renders alone (the env's own frames)
    camera = env.camera
    qpos = jnp.stack([jnp.asarray([*layout["agent_xy"], layout["agent_yaw"]]) for layout in layouts])
    zones = jnp.stack([layout["zone_xy"] for layout in layouts]).astype(jnp.float32)
    batched = jax.jit(jax.vmap(lambda q, z: camera.render(camera.scene(q, z))))(qpos, zones)
    for i in range(2):
        np.testing.assert_array_equal(batched[i], obs[i])


def test_shapes_dtypes_kinds_and_validation(moving_world):
    env, params, reset_to, *_ = moving_world
    obs, _ = reset_to(jax.random.key(0), _reference_layout(env), params)
    assert obs["image"].shape == (SIZE, SIZE, 3) and obs["image"].dtype == jnp.uint8
    assert env.observation_space.contains(jax.device_get(obs))
    assert env.obs_kinds == {"ap": "lidar", "ego": "vector", "image": "image"}
    plain, _ = specrl_jax.make("PointLTL1-v0")
    assert plain.obs_kinds == {"ap": "lidar", "ego": "vector"} and plain.camera is None
    assert "image" not in plain.observation_space.spaces
    wide, _ = specrl_jax.make("CarLTL2Vision-v0.partial", image_size=(32, 48))
    assert wide.observation_space["image"].shape == (32, 48, 3)
    assert wide.camera.zone_z == (0.0, 0.02)  # moving levels: zone bodies at z = 0.01
    assert ZoneConfig(vision=True).image_size == (256, 256)
    ids = [i for i in specrl_jax.list_envs() if "Vision" in i and "MA" not in i]
    assert len(ids) == 36 and "AntLTL0Vision-v0.partial_overlap" in ids
    for bad in (16, (32,), (32, 2048), True, 64.0):
        with pytest.raises(ValueError, match="image_size"):
            ZoneConfig(vision=True, image_size=bad)
    with pytest.raises(ValueError, match="fixed by the env ID"):
        specrl_jax.make("PointLTL0Vision-v0", vision=False)


def test_vision_id_passes_the_gymnasium_checker():
    env = gymnasium.make("PointLTL0Vision-v0", image_size=SIZE)
    space = env.observation_space
    assert list(space.keys())[-1] == "wall_sensor" and "vision" in space.keys()
    assert space["vision"].shape == (SIZE, SIZE, 3) and space["vision"].dtype == np.uint8
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*(minimum|maximum) value is (-)?infinity")
        check_env(env.unwrapped)
    obs, _ = env.reset(seed=1)
    assert space.contains(obs) and obs["vision"].dtype == np.uint8
    obs, reward, terminated, truncated, info = env.step(np.array([0.05, 0.0], np.float32))
    assert space.contains(obs) and reward == 0.0


# ---- the original's frame --------------------------------------------------------------------


def test_point_frame_matches_the_originals_reference_frame():
    # 2 x 2 supersampling (every class's IoU >= 0.958; 0.965 at 4 x 4, the lab script's default,
    # which renders 1024 x 1024: four times the compile and render time on a CPU)
    ours = FIDELITY.render_reference_layout("Point", supersample=2)
    scores = FIDELITY.iou(ours, FIDELITY.original_frame("Point"))
    assert set(scores) == {"sky", "wall", "floor", "green", "blue", "magenta", "robot"}
    assert min(scores.values()) >= 0.95, scores
