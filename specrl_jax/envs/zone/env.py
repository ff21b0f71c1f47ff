"""ZoneEnv: a robot (Point, Car, Ant) in MJX among coloured zones (static or moving)."""

from __future__ import annotations

import collections
import dataclasses
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.envs import spaces
from specrl_jax.envs.base import Env, Info, Obs
from specrl_jax.envs.zone import labels as labels_lib
from specrl_jax.envs.zone.camera import ZONE_RGB, Camera, zone_height
from specrl_jax.envs.zone.config import ZoneConfig
from specrl_jax.envs.zone.layout import check_feasible, from_bank, sample_bank, sample_positions
from specrl_jax.envs.zone.models import ROBOTS, load_model, start_height
from specrl_jax.envs.zone.motion import make_motion
from specrl_jax.envs.zone.physics import SUBSTEPS, Physics, PhysicsState, resolve_physics
from specrl_jax.envs.zone.sensors import compute_lidar, robot_sensor_reader, wall_sensor

ANT_FALL_HEIGHT = 0.08
#: The Ant's joint angles at an episode start before noise: hips 0, ankles +-pi/2, as the original.
ANT_START_JOINTS = (0.0, np.pi / 2, 0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, np.pi / 2)
ANT_JOINT_NOISE = 0.1


@struct.dataclass
class ZoneParams:
    """Values that may vary without changing compiled shapes.

    Attributes:
        max_steps: horizon, sets `truncated`.
        map_bank: None (default: an exact layout at every reset) or float32[M, 1 + Z, 2] agent
            and zone centres from `ZoneEnv.with_map_bank`, the opt-in fast reset.
    """

    max_steps: int = 1000
    map_bank: jax.Array | None = None


@struct.dataclass
class ZoneState:
    physics: PhysicsState  # the robot's MuJoCo state and the outputs observed
    start_qpos: jax.Array  # float32[nq], the robot's pose at the episode start
    zone_xy: jax.Array  # float32[Z, 2], zone (circle) centres, metres
    zone_direction: jax.Array  # float32[Z], +1 / -1 for moving zones, 0 for static ones
    zone_phase: jax.Array  # float32[Z], rad, phase of a moving zone at t = 0
    time: jax.Array  # int32, env steps since reset


def _yaw_quat(yaw: jax.Array) -> jax.Array:
    return jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])


class ZoneEnv(Env):
    """A robot among coloured zones on a 7 m x 7 m floor (the original's ZoneEnv).

    Observation: `ap: float32[P, 16]`, the pseudo-LiDAR of each colour (`env.propositions`
      order); `ego: float32[E + 4]`, the robot sensors of the original in alphabetical key
      order (Point 12, Car 24, Ant 40 values), then the wall sensor (east, south, west, north);
      with `config.vision`, `image: uint8[H, W, 3]`, the robot camera's RGB frame (`camera.py`).
    Action: `float32[2]` (Point: thrust, yaw servo; Car: wheel torques) or `float32[8]` (Ant
      joint torques), clipped to [-1, 1]; 10 physics substeps per step.
    Labels: colour p holds iff the agent body is within the radius of a zone of colour p.
    Termination: |x| or |y| >= 3.3 (the walls), the Ant's torso z <= 0.08. Reward: -1 on the
      step that crosses a wall, else 0 (the original's).
    State: `ZoneState`. Physics: `config.physics` resolved on this machine (`physics.backend`:
    "jax" MJX, or "warp" MuJoCo Warp through MJX).
    Resets: an exact layout each time, or opt-in draws from `with_map_bank`.
    Invalid actions: an eager call with NaN or inf in the action raises `ValueError`; under
      `jit` or `vmap` the step applies zeros instead, ends the episode (`terminated`) and sets
      `info["invalid_action"]` (False on valid steps), so the state stays finite;
      `envs.checked(env)` raises instead.
    """

    obs_kinds = {"ap": "lidar", "ego": "vector"}
    family = "zone"

    def __init__(self, config: ZoneConfig):
        if not isinstance(config, ZoneConfig):
            raise TypeError(f"config must be a ZoneConfig, got {type(config).__name__}")
        self.config = config
        self.robot = ROBOTS[config.robot]
        self.propositions = config.propositions
        self._num_parallel = check_feasible(config)
        solver = config.solver
        backend = resolve_physics(config.physics, config.robot)
        if backend != "jax":  # the contact cap is MJX-JAX's; Warp keeps its own buffer
            solver = dataclasses.replace(solver, max_contacts=0)
        self.mj_model = load_model(config.robot, solver)
        self.physics = Physics(
            self.mj_model, backend, config.solver.substep_sensors, config.solver.unroll,
            config.solver.small_cholesky,
        )
        self.start_height = start_height(config.robot, self.mj_model)
        self.frame_dt = SUBSTEPS * float(self.mj_model.opt.timestep)
        self.motion = make_motion(
            config.zone_motion, config.robot, config.travel, config.angular_speed, SUBSTEPS
        )
        colors = [c for c, n in zip(config.colors, config.zones_per_color) for _ in range(n)]
        self.zone_color = np.asarray([self.propositions.index(c) for c in colors], np.int32)
        self.zone_radius = np.asarray(
            [r for r, n in zip(config.zone_radius, config.zones_per_color) for _ in range(n)],
            np.float32,
        )
        self.zone_moving = np.asarray(
            [i < m for n, m in zip(config.zones_per_color, config.moving_per_color) for i in range(n)]
        )
        self.color_mask = self.zone_color[None, :] == np.arange(len(self.propositions))[:, None]
        self._alphabet = labels_lib.alphabet(config)
        self._read_robot_sensors = robot_sensor_reader(self.mj_model, self.robot)
        self._original_index = self._original_order()
        self.camera = None
        if config.vision:
            self.camera = Camera(
                self.mj_model, config.robot, np.asarray([ZONE_RGB[c] for c in colors]),
                self.zone_radius, zone_height(config.has_moving_zones), config.image_size,
            )
            self.obs_kinds = {**ZoneEnv.obs_kinds, "image": "image"}

    # ---- spaces -------------------------------------------------------------------------
    @property
    def default_params(self) -> ZoneParams:
        return ZoneParams(max_steps=self.config.horizon)

    @property
    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.robot.action_dim,), jnp.float32)

    @property
    def observation_space(self) -> spaces.Dict:
        parts = {
            "ap": spaces.Box(0.0, 1.0, (len(self.propositions), self.config.num_bins)),
            "ego": spaces.Box(-np.inf, np.inf, (self.robot.ego_size + 4,)),
        }
        if self.camera is not None:
            parts["image"] = spaces.Box(0, 255, (*self.config.image_size, 3), jnp.uint8)
        return spaces.Dict(parts)

    @property
    def alphabet(self) -> jax.Array:
        return jnp.asarray(self._alphabet)

    # ---- reset --------------------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: ZoneParams) -> tuple[Obs, ZoneState]:
        key_layout, key_pose = jax.random.split(key)
        if params.map_bank is None:
            xy, _ = sample_positions(key_layout, self.config, self._num_parallel)
        else:
            xy = from_bank(key_layout, params.map_bank)
        return self.reset_to(key_pose, self._random_layout(key_pose, xy), params)

    def with_map_bank(
        self, key: jax.Array, params: ZoneParams | None = None, num_maps: int = 65536
    ) -> ZoneParams:
        """Params whose resets draw agent and zone positions from `num_maps` exact layouts.

        Each reset takes a uniform bank entry under a uniform rotation or reflection of the
        square (8 of them); the agent's yaw, the Ant's joints and the moving zones' direction
        and phase stay fresh per episode. Each layout is still distributed as the original's,
        but positions repeat across resets (at most 8 x num_maps distinct). The bank costs
        8 (1 + Z) bytes per entry.
        """
        if not isinstance(num_maps, int) or isinstance(num_maps, bool) or num_maps < 1:
            raise ValueError(f"num_maps must be a positive int, got {num_maps!r}")
        params = self.default_params if params is None else params
        bank, ok = jax.jit(sample_bank, static_argnums=(1, 2, 3))(
            key, self.config, self._num_parallel, num_maps
        )
        if not bool(jnp.all(ok)):
            raise ValueError(
                f"{int((~ok).sum())} of {num_maps} layouts could not be placed within "
                f"max_restarts={self.config.max_restarts}; use fewer or smaller zones"
            )
        return params.replace(map_bank=bank.astype(jnp.float32))

    def _random_layout(self, key: jax.Array, xy: jax.Array) -> dict[str, jax.Array]:
        key_yaw, key_joints, key_direction, key_phase = jax.random.split(key, 4)
        num_zones = self.zone_color.shape[0]
        layout = {
            "agent_xy": xy[0],
            "agent_yaw": jax.random.uniform(key_yaw, (), minval=0.0, maxval=2 * jnp.pi),
            "zone_xy": xy[1:],
            "zone_color": jnp.asarray(self.zone_color),
            "zone_radius": jnp.asarray(self.zone_radius),
            "zone_direction": jnp.where(
                self.zone_moving,
                jnp.where(jax.random.bernoulli(key_direction, 0.5, (num_zones,)), 1.0, -1.0),
                0.0,
            ),
            "zone_phase": jnp.where(
                self.zone_moving,
                jax.random.uniform(key_phase, (num_zones,), minval=0.0, maxval=2 * jnp.pi),
                0.0,
            ),
        }
        if self.config.robot == "Car":
            layout["joint_qpos"] = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        elif self.config.robot == "Ant":
            # Hips near 0, ankles near +-pi/2 (ankle_2 and ankle_3 negative), as the original.
            noise = jax.random.uniform(key_joints, (8,), minval=-ANT_JOINT_NOISE, maxval=ANT_JOINT_NOISE)
            base = jnp.asarray(ANT_START_JOINTS, jnp.float32)
            sign = jnp.array([1.0, 1.0, 1.0, -1.0, 1.0, -1.0, 1.0, 1.0])
            layout["joint_qpos"] = base + sign * noise
        return layout

    def reset_to(self, key: jax.Array, layout: dict[str, Any], params: ZoneParams) -> tuple[Obs, ZoneState]:
        """Start an episode from `layout` (as returned by `layout`); `key` is unused (the
        start is deterministic). `zone_color` and `zone_radius` must be the config's."""
        del key, params
        agent_xy = jnp.asarray(layout["agent_xy"], jnp.float32)
        yaw = jnp.asarray(layout["agent_yaw"], jnp.float32)
        if self.config.robot == "Point":
            qpos = jnp.concatenate([agent_xy, yaw[None]])
        else:
            position = jnp.concatenate([agent_xy, jnp.array([self.start_height])])
            qpos = jnp.concatenate([position, _yaw_quat(yaw), jnp.asarray(layout["joint_qpos"])])
        state = ZoneState(
            physics=self.physics.init(qpos),
            start_qpos=qpos,
            zone_xy=jnp.asarray(layout["zone_xy"], jnp.float32),
            zone_direction=jnp.asarray(layout["zone_direction"], jnp.float32),
            zone_phase=jnp.asarray(layout["zone_phase"], jnp.float32),
            time=jnp.zeros((), jnp.int32),
        )
        return self._observe(state), state

    # ---- step ---------------------------------------------------------------------------
    def step_env(
        self, key: jax.Array, state: ZoneState, action: jax.Array, params: ZoneParams
    ) -> tuple[Obs, ZoneState, jax.Array, jax.Array, Info]:
        del key, params
        physics = self.physics.step(state.physics, action)
        state = state.replace(physics=physics, time=state.time + 1)
        position = physics.agent_pos
        outside = jnp.any(jnp.abs(position[:2]) >= self.config.wall)
        fallen = position[2] <= ANT_FALL_HEIGHT if self.config.robot == "Ant" else False
        info = {"propositions": self._labels(state)}
        reward = jnp.where(outside, -1.0, 0.0).astype(jnp.float32)  # the original's wall reward
        return self._observe(state), state, reward, outside | fallen, info

    def zone_positions(self, state: ZoneState) -> jax.Array:
        """float32[Z, 2]: current zone centres, metres. A moving zone follows a command on the
        circle of radius `travel` about its layout centre, at angle `angular_speed * t *
        direction + phase` (sim time t, from +y towards +x for direction +1); with
        `zone_motion="weld"` (default) it starts at the layout centre and trails the command as
        the original's welded zone body does, with "circle" it is on the command itself
        (`motion.py`)."""
        if not self.config.has_moving_zones:
            return state.zone_xy
        offsets = self.motion.offsets(state.time, state.zone_direction, state.zone_phase)
        return state.zone_xy + offsets

    def _labels(self, state: ZoneState) -> jax.Array:
        return labels_lib.compute_labels(
            state.physics.agent_pos[:2], self.zone_positions(state), jnp.asarray(self.zone_radius),
            jnp.asarray(self.color_mask),
        )

    def _observe(self, state: ZoneState) -> Obs:
        physics = state.physics
        ap = compute_lidar(
            physics.agent_pos, physics.agent_mat, self.zone_positions(state), jnp.asarray(self.color_mask),
            self.config.num_bins, self.config.partial,
        )
        ego = jnp.concatenate(
            [
                self._read_robot_sensors(physics.sensordata),
                wall_sensor(physics.agent_pos[:2], self.config.wall),
            ]
        )
        obs = {"ap": ap.astype(jnp.float32), "ego": ego.astype(jnp.float32)}
        if self.camera is not None:
            scene = self.camera.scene(physics.qpos, self.zone_positions(state))
            obs["image"] = self.camera.render(scene)
        return obs

    # ---- layout and the original's flat observation ------------------------------------
    def layout(self, state: ZoneState) -> dict[str, jax.Array]:
        """The layout the episode started from: `agent_xy float32[2]` (m), `agent_yaw` (rad,
        counter-clockwise from +x, of the body x axis), `zone_xy float32[Z, 2]` (circle centres
        for moving zones), `zone_color int32[Z]` (index into `propositions`), `zone_radius
        float32[Z]`, `zone_direction float32[Z]` (+-1 moving, 0 static), `zone_phase float32[Z]`
        (rad), and for Car and Ant `joint_qpos` (the qpos after the free joint)."""
        qpos = state.start_qpos
        if self.config.robot == "Point":
            yaw = qpos[2]
        else:
            yaw = 2.0 * jnp.arctan2(qpos[6], qpos[3])
        layout = {
            "agent_xy": qpos[:2],
            "agent_yaw": jnp.mod(yaw, 2 * jnp.pi),
            "zone_xy": state.zone_xy,
            "zone_color": jnp.asarray(self.zone_color),
            "zone_radius": jnp.asarray(self.zone_radius),
            "zone_direction": state.zone_direction,
            "zone_phase": state.zone_phase,
        }
        if self.config.robot != "Point":
            layout["joint_qpos"] = qpos[7:]
        return layout

    def _original_order(self) -> np.ndarray:
        """Indices into `concat([ego, ap.ravel()])` giving the original's flat vector."""
        ranges, offset = {}, 0
        for name, size in self.robot.ego_keys:
            ranges[name] = np.arange(offset, offset + size)
            offset += size
        wall = np.arange(offset, offset + 4)
        offset += 4
        bins = self.config.num_bins
        for p, color in enumerate(self.propositions):
            ranges[f"{color}_zones_lidar"] = np.arange(offset + p * bins, offset + (p + 1) * bins)
        return np.concatenate([ranges[k] for k in sorted(ranges)] + [wall])

    def _original_keys(self) -> list[tuple[str, tuple[int, ...]]]:
        """The original's observation keys and shapes, in its flat vector's order."""
        sizes = dict(self.robot.ego_keys)
        sizes |= {f"{c}_zones_lidar": self.config.num_bins for c in self.propositions}
        shapes = {name: (3, 3) if name == "ballquat_rear" else (size,) for name, size in sizes.items()}
        return [(name, shapes[name]) for name in sorted(shapes)] + [("wall_sensor", (4,))]

    @property
    def original_observation_space(self) -> gymnasium.spaces.Space:
        """The original's flattened observation: keys alphabetical, `wall_sensor` last. With
        `config.vision`, the original's dict instead: each of those keys apart (same order,
        `ballquat_rear` 3 x 3) and `vision`, uint8[H, W, 3], in its alphabetical place."""
        if self.camera is not None:
            return self._original_dict_space()
        return self._original_flat_space()

    def _original_flat_space(self) -> gymnasium.spaces.Box:
        ego_size = self.robot.ego_size
        size = self._original_index.shape[0]
        low = np.full(size, -np.inf, np.float32)
        high = np.full(size, np.inf, np.float32)
        bounded = self._original_index >= ego_size  # wall sensor and LiDAR are in [0, 1]
        low[bounded], high[bounded] = 0.0, 1.0
        return gymnasium.spaces.Box(low, high, (size,), np.float32)

    def original_observation(self, obs: Obs) -> jax.Array | dict[str, jax.Array]:
        """float32[80 | 92 | 108]: `obs` in the original's flat layout (works batched); with
        `config.vision` the original's dict (see `original_observation_space`)."""
        ap = obs["ap"].reshape(*obs["ap"].shape[:-2], -1)
        flat = jnp.concatenate([obs["ego"], ap], axis=-1)[..., self._original_index]
        if self.camera is None:
            return flat
        parts, offset = {}, 0
        for name, shape in self._original_keys():
            size = int(np.prod(shape))
            parts[name] = flat[..., offset:offset + size].reshape(*flat.shape[:-1], *shape)
            offset += size
        return self._with_vision(parts, obs["image"])

    @staticmethod
    def _with_vision(parts: dict, vision: Any) -> dict:
        """The original's dict order: keys alphabetical (`vision` among them), `wall_sensor` last."""
        named = {**{k: v for k, v in parts.items() if k != "wall_sensor"}, "vision": vision}
        return {k: named[k] for k in sorted(named)} | {"wall_sensor": parts["wall_sensor"]}

    def _original_dict_space(self) -> gymnasium.spaces.Dict:
        flat = self._original_flat_space()
        parts, offset = {}, 0
        for name, shape in self._original_keys():
            size = int(np.prod(shape))
            low, high = flat.low[offset:offset + size], flat.high[offset:offset + size]
            parts[name] = gymnasium.spaces.Box(low.reshape(shape), high.reshape(shape), shape, np.float32)
            offset += size
        vision = gymnasium.spaces.Box(0, 255, (*self.config.image_size, 3), np.uint8)
        return gymnasium.spaces.Dict(collections.OrderedDict(self._with_vision(parts, vision)))
