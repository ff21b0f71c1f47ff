"""ZoneEnv: a robot (Point, Car, Ant) in MJX among coloured zones (static or moving)."""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.envs import spaces
from specrl_jax.envs.base import Env, Info, Obs
from specrl_jax.envs.zone import labels as labels_lib
from specrl_jax.envs.zone.config import ZoneConfig
from specrl_jax.envs.zone.layout import check_feasible, sample_positions
from specrl_jax.envs.zone.mjx_import import mjx
from specrl_jax.envs.zone.models import ROBOTS, load_model
from specrl_jax.envs.zone.sensors import compute_lidar, robot_sensor_reader, wall_sensor

SUBSTEPS = 10
ANT_FALL_HEIGHT = 0.08
ANT_JOINT_NOISE = 0.1


@struct.dataclass
class ZoneParams:
    max_steps: int = 1000


@struct.dataclass
class ZoneState:
    data: mjx.Data  # physics state of the robot
    start_qpos: jax.Array  # float32[nq], the robot's pose at the episode start
    zone_xy: jax.Array  # float32[Z, 2], zone (circle) centres, metres
    zone_direction: jax.Array  # float32[Z], +1 / -1 for moving zones, 0 for static ones
    zone_phase: jax.Array  # float32[Z], rad, phase of a moving zone at t = 0
    time: jax.Array  # int32, env steps since reset


def _has_no_constraints(model: mjx.Model) -> bool:
    return jax.eval_shape(mjx.make_data, model)._impl.efc_J.size == 0


def _yaw_quat(yaw: jax.Array) -> jax.Array:
    return jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])


class ZoneEnv(Env):
    """A robot among coloured zones on a 7 m x 7 m floor (the original's ZoneEnv).

    Observation: `ap: float32[P, 16]`, the pseudo-LiDAR of each colour (`env.propositions`
      order); `ego: float32[E + 4]`, the robot sensors of the original in alphabetical key
      order (Point 12, Car 24, Ant 40 values), then the wall sensor (east, south, west, north).
    Action: `float32[2]` (Point: thrust, yaw servo; Car: wheel torques) or `float32[8]` (Ant
      joint torques), clipped to [-1, 1]; 10 physics substeps per step.
    Labels: colour p holds iff the agent body is within the radius of a zone of colour p.
    Termination: |x| or |y| >= 3.3 (the walls), the Ant's torso z <= 0.08. Reward: always 0.
    State: `ZoneState`.
    """

    def __init__(self, config: ZoneConfig):
        if not isinstance(config, ZoneConfig):
            raise TypeError(f"config must be a ZoneConfig, got {type(config).__name__}")
        self.config = config
        self.robot = ROBOTS[config.robot]
        self.propositions = config.propositions
        self._num_parallel = check_feasible(config)
        self.mj_model = load_model(config.robot, config.solver)
        self.mjx_model = mjx.put_model(self.mj_model)
        # MJX's forward skips the acceleration sensors of a model without any constraint row
        # (the pruned Point); they are then computed here, as MuJoCo C always does.
        self._add_sensor_acc = self.mj_model.nsensor > 0 and _has_no_constraints(self.mjx_model)
        self.frame_dt = SUBSTEPS * float(self.mj_model.opt.timestep)
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

    # ---- spaces -------------------------------------------------------------------------
    @property
    def default_params(self) -> ZoneParams:
        return ZoneParams(max_steps=self.config.horizon)

    @property
    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.robot.action_dim,), jnp.float32)

    @property
    def observation_space(self) -> spaces.Dict:
        return spaces.Dict(
            {
                "ap": spaces.Box(0.0, 1.0, (len(self.propositions), self.config.num_bins)),
                "ego": spaces.Box(-np.inf, np.inf, (self.robot.ego_size + 4,)),
            }
        )

    @property
    def alphabet(self) -> jax.Array:
        return jnp.asarray(self._alphabet)

    # ---- reset --------------------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: ZoneParams) -> tuple[Obs, ZoneState]:
        key_layout, key_pose = jax.random.split(key)
        xy, _ = sample_positions(key_layout, self.config, self._num_parallel)
        return self.reset_to(key_pose, self._random_layout(key_pose, xy), params)

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
            base = jnp.array([0.0, 1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0]) * (jnp.pi / 2)
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
            position = jnp.concatenate([agent_xy, jnp.array([self.robot.z_height])])
            qpos = jnp.concatenate([position, _yaw_quat(yaw), jnp.asarray(layout["joint_qpos"])])
        data = mjx.make_data(self.mjx_model)
        data = data.replace(qpos=qpos.astype(data.qpos.dtype))
        data = self._forward(data)
        state = ZoneState(
            data=data,
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
        data = self._simulate(state.data, action)
        state = state.replace(data=data, time=state.time + 1)
        position = data.xpos[1]
        outside = jnp.any(jnp.abs(position[:2]) >= self.config.wall)
        fallen = position[2] <= ANT_FALL_HEIGHT if self.config.robot == "Ant" else False
        info = {"propositions": self._labels(state)}
        return self._observe(state), state, jnp.zeros((), jnp.float32), outside | fallen, info

    def _simulate(self, data: mjx.Data, action: jax.Array) -> mjx.Data:
        """10 physics substeps, then the forward pass the original runs before sensing."""
        data = data.replace(ctrl=jnp.clip(action, -1.0, 1.0).astype(data.ctrl.dtype))
        data = jax.lax.fori_loop(0, SUBSTEPS, lambda _, d: mjx.step(self.mjx_model, d), data)
        return self._forward(data)

    def _forward(self, data: mjx.Data) -> mjx.Data:
        data = mjx.forward(self.mjx_model, data)
        return mjx.sensor_acc(self.mjx_model, data) if self._add_sensor_acc else data

    def zone_positions(self, state: ZoneState) -> jax.Array:
        """float32[Z, 2]: current zone centres, metres. A moving zone runs a circle of radius
        `travel` about its layout centre, starting (sim time t = 0) at angle `zone_phase`
        from +y towards +x for direction +1: `centre + travel * (sin(a), cos(a))`,
        `a = angular_speed * t * direction + phase`."""
        sim_time = state.time.astype(jnp.float32) * self.frame_dt
        angle = self.config.angular_speed * sim_time * state.zone_direction + state.zone_phase
        circle = jnp.stack([jnp.sin(angle), jnp.cos(angle)], axis=-1)
        return state.zone_xy + self.config.travel * jnp.abs(state.zone_direction)[:, None] * circle

    def _labels(self, state: ZoneState) -> jax.Array:
        return labels_lib.compute_labels(
            state.data.xpos[1, :2], self.zone_positions(state), jnp.asarray(self.zone_radius),
            jnp.asarray(self.color_mask),
        )

    def _observe(self, state: ZoneState) -> Obs:
        data = state.data
        ap = compute_lidar(
            data.xpos[1], data.xmat[1], self.zone_positions(state), jnp.asarray(self.color_mask),
            self.config.num_bins, self.config.partial,
        )
        ego = jnp.concatenate(
            [self._read_robot_sensors(data.sensordata), wall_sensor(data.xpos[1, :2], self.config.wall)]
        )
        return {"ap": ap.astype(jnp.float32), "ego": ego.astype(jnp.float32)}

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

    @property
    def original_observation_space(self) -> gymnasium.spaces.Box:
        """The original's flattened observation: keys alphabetical, `wall_sensor` last."""
        ego_size = self.robot.ego_size
        size = self._original_index.shape[0]
        low = np.full(size, -np.inf, np.float32)
        high = np.full(size, np.inf, np.float32)
        bounded = self._original_index >= ego_size  # wall sensor and LiDAR are in [0, 1]
        low[bounded], high[bounded] = 0.0, 1.0
        return gymnasium.spaces.Box(low, high, (size,), np.float32)

    def original_observation(self, obs: Obs) -> jax.Array:
        """float32[80 | 92 | 108]: `obs` in the original's flat layout (works batched)."""
        ap = obs["ap"].reshape(*obs["ap"].shape[:-2], -1)
        return jnp.concatenate([obs["ego"], ap], axis=-1)[..., self._original_index]
