"""ArmEnv: the original's 7-DoF Panda reaching coloured spheres, in MJX (`PandaLTLReach*`)."""

from __future__ import annotations

import itertools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.envs import spaces
from specrl_jax.envs.arm import layout as layout_lib
from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm import sensors
from specrl_jax.envs.arm.config import ArmConfig
from specrl_jax.envs.arm.ik import EndEffectorIK
from specrl_jax.envs.arm.physics import Physics, PhysicsState
from specrl_jax.envs.base import Env, Info, Obs, sampler_check

ACTION_SCALE = 0.05  # rad of joint target per unit action


@struct.dataclass
class ArmParams:
    """Values that may vary without changing compiled shapes.

    Attributes:
        max_steps: horizon, sets `truncated`.
        map_bank: None (default: an exact layout at every reset) or float32[M, Z, 3] region
            centres from `ArmEnv.with_map_bank`, the fast reset (training's default).
    """

    max_steps: int = 200
    map_bank: jax.Array | None = None


@struct.dataclass
class ArmState:
    physics: PhysicsState  # joint angles and velocities
    region_pos: jax.Array  # float32[Z, 3], sphere centres, metres (never move)
    start_qpos: jax.Array  # float32[7], the joint angles the episode started from
    layout_ok: jax.Array  # bool[], False if the sampler gave up (see ArmConfig.max_rounds)
    time: jax.Array  # int32, env steps since reset


class ArmEnv(Env):
    """The Panda arm among coloured spheres on a table (the original's PandaLTLReach*: joint or
    end-effector control).

    Observation: `ego` float32[6] (mode 0: grasp-target position and linear velocity, world
      frame) or float32[70] (mode 1: per link COM position and xyzw quaternion, 10 links);
      `ap` float32[P, 4] (mode 0: `[dir_x, dir_y, dir_z, dist]` to the nearest region of each
      colour) or float32[P, 8, 4] (mode 1: per link, arm propositions 8 links, gripper
      propositions the 2 fingers then zero rows).
    Action: in [-1, 1] (clipped; NaN/inf: see `base.Env.step`); joint control float32[7]: joint
      targets q + 0.05 a; end-effector control float32[3]: joint targets from PyBullet's IK
      for the grasp target moved by 0.05 a (m, z >= 0, gripper down; `arm/ik.py`). Then 20
      physics substeps of 2 ms (dt 0.04 s) under PyBullet's emulated position motor.
    Labels: mode 0 `<colour>`: grasp target within a region; mode 1 `arm_<colour>`: an arm link
      (links 1-7, hand) touches or penetrates a region, `grippers_<colour>`: both fingers do.
    Termination: never (reward 0); the horizon (200) truncates.
    State: `ArmState`.
    """

    obs_kinds = {"ap": "range_bearing", "ego": "vector"}
    family = "arm"

    def __init__(self, config: ArmConfig):
        if not isinstance(config, ArmConfig):
            raise TypeError(f"config must be an ArmConfig, got {type(config).__name__}")
        layout_lib.check_feasible(config)  # raises if the keep-out leaves no layouts
        self.config = config
        self.propositions = config.propositions
        self.same_object = config.same_object
        self.mj_model = arm_model.load_model(config.table_contacts)
        self.physics = Physics(self.mj_model, arm_model.FORCE_LIMITS, motor_solve=config.motor_solve)
        self.ik = EndEffectorIK(self.mj_model)
        self._link_ids = arm_model.body_ids(self.mj_model)
        self._grasp_id = int(self.mj_model.site(arm_model.GRASP_SITE).id)
        self._triangles = arm_model.link_hulls()
        colors = [c for c in config.colors for _ in range(config.regions_per_color)]
        self.region_color = np.asarray([config.colors.index(c) for c in colors], np.int32)
        self.region_radius = np.full(config.num_regions, config.region_radius, np.float32)
        # colour order of the features: the propositions' (sorted) colour order
        self._colors = tuple(sorted(config.colors))
        self.color_mask = np.asarray([[c == k for c in colors] for k in self._colors])
        self._alphabet = self._make_alphabet()
        self.joint_low = self.mj_model.jnt_range[:, 0].astype(np.float32)
        self.joint_high = self.mj_model.jnt_range[:, 1].astype(np.float32)

    # ---- spaces -------------------------------------------------------------------------
    @property
    def default_params(self) -> ArmParams:
        return ArmParams(max_steps=self.config.horizon)

    @property
    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (7 if self.config.control == "joints" else 3,), jnp.float32)

    @property
    def ap_shape(self) -> tuple[int, ...]:
        p = len(self.propositions)
        return (p, 4) if self.config.mode == 0 else (p, arm_model.NUM_ARM_LINKS, 4)

    @property
    def observation_space(self) -> spaces.Dict:
        ego = 6 if self.config.mode == 0 else 7 * len(arm_model.LINK_BODIES)
        return spaces.Dict(
            {"ap": spaces.Box(-1.0, 2.0, self.ap_shape), "ego": spaces.Box(-10.0, 10.0, (ego,))}
        )

    def _make_alphabet(self) -> np.ndarray:
        p = len(self.propositions)
        if self.config.mode == 0:  # regions never overlap: at most one colour holds
            return np.concatenate([np.zeros((1, p), bool), np.eye(p, dtype=bool)])
        return np.asarray(list(itertools.product([False, True], repeat=p)), bool)

    @property
    def alphabet(self) -> jax.Array:
        return jnp.asarray(self._alphabet)

    # ---- reset --------------------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: ArmParams) -> tuple[Obs, ArmState]:
        if params.map_bank is None:
            centres, ok = layout_lib.sample_centres(key, self.config)
            rounds = self.config.max_rounds
            sampler_check(
                ok, f"the arm's layout sampler found no valid layout in max_rounds={rounds} rounds"
            )
        else:
            bank = jnp.asarray(params.map_bank)
            centres, ok = bank[jax.random.randint(key, (), 0, bank.shape[0])], jnp.array(True)
        layout = {"region_pos": centres, "joint_qpos": jnp.asarray(arm_model.NEUTRAL_QPOS)}
        obs, state = self.reset_to(key, layout, params)
        return obs, state.replace(layout_ok=ok)

    def with_map_bank(self, key: jax.Array, params: ArmParams | None = None,
                      num_maps: int = 65536) -> ArmParams:
        """Params whose resets draw region centres uniformly from `num_maps` exact layouts
        (each distributed as the original's; layouts repeat across resets)."""
        if not isinstance(num_maps, int) or isinstance(num_maps, bool) or num_maps < 1:
            raise ValueError(f"num_maps must be a positive int, got {num_maps!r}")
        params = self.default_params if params is None else params
        sample = jax.jit(layout_lib.sample_bank, static_argnums=(1, 2))
        bank, ok = sample(key, self.config, num_maps)
        if not bool(jnp.all(ok)):
            raise ValueError(f"{int((~ok).sum())} of {num_maps} layouts could not be placed")
        return params.replace(map_bank=bank.astype(jnp.float32))

    def reset_to(
        self, key: jax.Array, layout: dict[str, Any], params: ArmParams
    ) -> tuple[Obs, ArmState]:
        """Start from `layout` (`region_pos float[Z, 3]`, optional `joint_qpos float[7]`, default
        the neutral pose); the arm starts at rest. `key` is unused (the start is deterministic)."""
        del key, params
        qpos = jnp.asarray(layout.get("joint_qpos", arm_model.NEUTRAL_QPOS), jnp.float32)
        state = ArmState(
            physics=self.physics.init(qpos),
            region_pos=jnp.asarray(layout["region_pos"], jnp.float32),
            start_qpos=qpos,
            layout_ok=jnp.array(True),
            time=jnp.zeros((), jnp.int32),
        )
        obs, _ = self._observe(state)
        return obs, state

    def layout(self, state: ArmState) -> dict[str, jax.Array]:
        """`region_pos float32[Z, 3]` (m), `region_color int32[Z]` (index into
        `config.colors`), `region_radius float32[Z]` (m), `joint_qpos float32[7]` (rad, the
        episode's start)."""
        return {
            "region_pos": state.region_pos,
            "region_color": jnp.asarray(self.region_color),
            "region_radius": jnp.asarray(self.region_radius),
            "joint_qpos": state.start_qpos,
        }

    # ---- step ---------------------------------------------------------------------------
    def step_env(self, key: jax.Array, state: ArmState, action: jax.Array,
                 params: ArmParams) -> tuple[Obs, ArmState, jax.Array, jax.Array, Info]:
        del key, params
        action = jnp.clip(jnp.nan_to_num(jnp.asarray(action, jnp.float32)), -1.0, 1.0)
        if self.config.control == "joints":
            target = state.physics.qpos + ACTION_SCALE * action
        else:
            target = self.ik.joint_targets(state.physics.qpos, action)
        state = state.replace(physics=self.physics.step(state.physics, target), time=state.time + 1)
        obs, label = self._observe(state)
        return obs, state, jnp.zeros((), jnp.float32), jnp.array(False), {"propositions": label}

    def label(self, state: ArmState) -> jax.Array:
        """bool[P]: the propositions that hold in `state`."""
        return self._observe(state)[1]

    def poses(self, state: ArmState) -> dict[str, jax.Array]:
        """World poses at the current joint angles: `link_pos`, `link_mat` (frames, [10, 3] and
        [10, 3, 3]), `com_pos` [10, 3], `com_quat` [10, 4] (xyzw), `grasp_pos` [3],
        `grasp_vel` [3] (m/s)."""
        data = self.physics.data(state.physics)
        ids = jnp.asarray(self._link_ids)
        grasp = data.site_xpos[self._grasp_id]
        # every joint moves the hand: the grasp target's velocity is sum_j axis_j x (p - anchor_j)
        jacp = jnp.cross(data.xaxis, grasp - data.xanchor)  # [7, 3]
        quat = data.xquat[ids]
        return {
            "link_pos": data.xpos[ids],
            "link_mat": data.xmat[ids],
            "com_pos": data.xipos[ids],
            "com_quat": jnp.concatenate([quat[:, 1:], quat[:, :1]], axis=-1),
            "grasp_pos": grasp,
            "grasp_vel": jacp.T @ state.physics.qvel,
        }

    def _observe(self, state: ArmState) -> tuple[Obs, jax.Array]:
        pose = self.poses(state)
        centres, radius = state.region_pos, jnp.asarray(self.region_radius)
        mask = jnp.asarray(self.color_mask)
        if self.config.mode == 0:
            ap, label = sensors.point_features(pose["grasp_pos"], centres, radius, mask,
                                               self.config.partial)
            ego = jnp.concatenate([pose["grasp_pos"], pose["grasp_vel"]])
        else:
            dist, normal = sensors.link_sphere_distances(
                pose["link_pos"], pose["link_mat"], self._triangles, centres, radius
            )
            features, arm, grippers = sensors.link_features(
                dist, normal, mask, arm_model.NUM_ARM_LINKS, self.config.partial
            )
            n = arm_model.NUM_ARM_LINKS
            finger_rows = jnp.zeros_like(features[:, :n]).at[:, : features.shape[1] - n].set(
                features[:, n:]
            )
            ap = jnp.concatenate([features[:, :n], finger_rows], axis=0)  # arm_*, then grippers_*
            label = jnp.concatenate([arm, grippers])
            ego = jnp.concatenate([pose["com_pos"], pose["com_quat"]], axis=-1).reshape(-1)
        return {"ap": ap.astype(jnp.float32), "ego": ego.astype(jnp.float32)}, label

    # ---- the original's dict observation ------------------------------------------------
    def _original_keys(self) -> list[tuple[str, Any]]:
        """(key, (ap row, rows)) in the original's insertion order."""
        keys = []
        for c in self.config.colors:  # the original's colour order
            if self.config.mode == 0:
                keys.append((f"dist_to_{c}", (self.propositions.index(c), None)))
            else:
                keys.append((f"dist_to_arm_{c}", (self.propositions.index(f"arm_{c}"), 8)))
                grippers = self.propositions.index(f"grippers_{c}")
                keys.append((f"dist_to_grippers_{c}", (grippers, 2)))
        return keys

    @property
    def original_observation_space(self) -> gymnasium.spaces.Dict:
        """The original's keys: `ego_state`, then `dist_to_<c>` (mode 0, [4]) or
        `dist_to_arm_<c>` [8, 4] and `dist_to_grippers_<c>` [2, 4] (mode 1), declared here
        (the original declares only `ego_state`)."""
        ego = self.observation_space["ego"].shape
        out = {"ego_state": gymnasium.spaces.Box(-10.0, 10.0, ego, np.float32)}
        for key, (_, rows) in self._original_keys():
            shape = (4,) if rows is None else (rows, 4)
            low = np.broadcast_to(np.array([-1, -1, -1, 0], np.float32), shape)
            high = np.broadcast_to(np.array([1, 1, 1, 2], np.float32), shape)
            out[key] = gymnasium.spaces.Box(low.copy(), high.copy(), shape, np.float32)
        return gymnasium.spaces.Dict(out)

    def original_observation(self, obs: Obs) -> dict[str, jax.Array]:
        """`obs` under the original's keys (unbatched)."""
        out = {"ego_state": obs["ego"]}
        for key, (row, rows) in self._original_keys():
            out[key] = obs["ap"][row] if rows is None else obs["ap"][row, :rows]
        return out

