"""MultiZoneEnv: N robots among coloured zones, each seeing the single-agent Zone sensors plus a
pseudo-LiDAR of the other agents; every agent of a world steps in one batched MJX call."""

from __future__ import annotations

import functools
import itertools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.envs import spaces
from specrl_jax.envs.base import Env, Info, Obs
from specrl_jax.envs.multi import layout as layout_lib
from specrl_jax.envs.multi.config import MultiZoneConfig
from specrl_jax.envs.multi.original import OriginalLayout
from specrl_jax.envs.zone import labels as zone_labels
from specrl_jax.envs.zone import layout as zone_layout
from specrl_jax.envs.zone.env import ZoneEnv, ZoneState
from specrl_jax.envs.zone.sensors import compute_lidar

#: layout keys that hold one value per agent (leading axis N); the others describe the zones
AGENT_KEYS = ("agent_xy", "agent_yaw", "joint_qpos")


@struct.dataclass
class MultiZoneParams:
    """Values that may vary without changing compiled shapes.

    Attributes:
        max_steps: horizon, sets `truncated`.
        collisions: bool, whether an agent terminates when another one is within
            `collision_distance` (defaults from the config; off: the paper's protocol).
        collision_distance: float, planar centre distance, metres.
        map_bank: None (default: an exact layout at every reset) or float32[M, Z + N, 2] zone
            and agent centres from `MultiZoneEnv.with_map_bank`, the opt-in fast reset.
    """

    max_steps: int = 1000
    collisions: bool | jax.Array = False
    collision_distance: float | jax.Array = 0.28
    map_bank: jax.Array | None = None


@struct.dataclass
class MultiZoneState:
    agents: ZoneState  # leading axis N: each robot's state (zone fields the same in every row)
    terminated: jax.Array  # bool[N], sticky: the agent left the arena, fell or collided
    time: jax.Array  # int32, env steps since reset


class MultiZoneEnv(Env):
    """N robots among coloured zones on a 7 m x 7 m floor (the original's `PointLTL0MA3-v0`).

    Stacked arrays are the functional contract (the JaxMARL dict view is `agent_obs` /
    `stack_actions`, with agent names `env.agents`):
    Observation: `ap: float32[N, P, 16]` each agent's pseudo-LiDAR of each colour (colours
      sorted, as single-agent `obs["ap"]`); `ego: float32[N, E + 4]` its robot sensors and wall
      sensor (as single-agent `obs["ego"]`); `others: float32[N, 1, 16]` its pseudo-LiDAR of
      the other agents' bodies (own body removed).
    Action: `float32[N, A]`, agent i's row as the single-agent robot's action.
    Labels: `info["propositions"] bool[N * P]` over `env.propositions` = `<colour>_<i>`
      agent-major (agent 0's colours, then agent 1's, ...); `info["symbol"]` its alphabet row.
    Termination: per agent, `bool[N]`: the agent left the arena (|x| or |y| >= wall), the Ant
      fell, or (`config.collisions`) another agent is within `collision_distance`. It is sticky
      until the world resets; a terminated agent's actions are ignored (zero control).
      `truncated bool[N]` at the horizon for agents not terminated. The world's episode ends when
      every agent is done (`episode_done`; `MultiAutoReset` resets then). Reward: `float32[N]` 0.
    State: `MultiZoneState`. Physics: the single-agent robot model stepped for all N agents
      by one `vmap` over MJX; agents do not touch each other physically (docs/fidelity.md).
    """

    obs_kinds = {"ap": "lidar", "ego": "vector", "others": "lidar"}
    family = "multi_agent_zone"

    def __init__(self, config: MultiZoneConfig):
        if not isinstance(config, MultiZoneConfig):
            raise TypeError(f"config must be a MultiZoneConfig, got {type(config).__name__}")
        self.config = config
        self.world = ZoneEnv(config.zone_config)
        self.agents = config.agents
        self.num_agents = config.num_agents
        self.propositions = config.propositions
        self.colour_propositions = self.world.propositions
        layout_lib.check_feasible(config)
        self._agent_alphabet = zone_labels.alphabet(config.zone_config)
        self._base = self._agent_alphabet.shape[0]
        if self._base**self.num_agents >= 2**31:
            raise ValueError(
                f"{self.num_agents} agents x {self._base} labels each give more than 2^31 joint "
                "labels; use fewer agents"
            )
        self._others = np.asarray(
            [[j for j in range(self.num_agents) if j != i] for i in range(self.num_agents)],
            np.int32,
        ).reshape(self.num_agents, self.num_agents - 1)

    # ---- spaces -------------------------------------------------------------------------
    @property
    def default_params(self) -> MultiZoneParams:
        return MultiZoneParams(
            max_steps=self.config.horizon,
            collisions=self.config.collisions,
            collision_distance=self.config.collision_distance,
        )

    @property
    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.num_agents, self.world.robot.action_dim), jnp.float32)

    @property
    def observation_space(self) -> spaces.Dict:
        single = self.world.observation_space
        bins = self.config.zone_config.num_bins
        return spaces.Dict(
            {
                "ap": spaces.Box(0.0, 1.0, (self.num_agents, *single["ap"].shape)),
                "ego": spaces.Box(-np.inf, np.inf, (self.num_agents, *single["ego"].shape)),
                "others": spaces.Box(0.0, 1.0, (self.num_agents, 1, bins)),
            }
        )

    @functools.cached_property
    def _alphabet(self) -> np.ndarray:
        rows = itertools.product(self._agent_alphabet, repeat=self.num_agents)
        return np.asarray([np.concatenate(r) for r in rows], bool)

    @property
    def alphabet(self) -> jax.Array:
        """`bool[A ** N, N * P]`: the product over agents of one agent's labels (none or one
        colour, or every subset where zones can overlap); agent 0 varies slowest."""
        return jnp.asarray(self._alphabet)

    # ---- reset --------------------------------------------------------------------------
    def reset_env(self, key: jax.Array, params: MultiZoneParams) -> tuple[Obs, MultiZoneState]:
        key_layout, key_pose = jax.random.split(key)
        if params.map_bank is None:
            zone_xy, agent_xy, _ = layout_lib.sample_positions(key_layout, self.config)
        else:
            xy = zone_layout.from_bank(key_layout, params.map_bank)
            zone_xy, agent_xy = xy[: -self.num_agents], xy[-self.num_agents :]
        return self.reset_to(key_pose, self._random_layout(key_pose, zone_xy, agent_xy), params)

    def with_map_bank(
        self, key: jax.Array, params: MultiZoneParams | None = None, num_maps: int = 65536
    ) -> MultiZoneParams:
        """Params whose resets draw zone and agent centres from `num_maps` exact layouts, each
        under a uniform rotation or reflection of the square (as `ZoneEnv.with_map_bank`); yaws
        stay fresh per episode. Positions repeat across resets (at most 8 x num_maps)."""
        if not isinstance(num_maps, int) or isinstance(num_maps, bool) or num_maps < 1:
            raise ValueError(f"num_maps must be a positive int, got {num_maps!r}")
        params = self.default_params if params is None else params
        sample = jax.jit(jax.vmap(lambda k: layout_lib.sample_positions(k, self.config)))
        zone_xy, agent_xy, ok = sample(jax.random.split(key, num_maps))
        if not bool(jnp.all(ok)):
            raise ValueError(
                f"{int((~ok).sum())} of {num_maps} layouts could not be placed within "
                f"max_restarts={self.config.max_restarts}; use fewer agents or zones"
            )
        bank = jnp.concatenate([zone_xy, agent_xy], axis=1).astype(jnp.float32)
        return params.replace(map_bank=bank)

    def _random_layout(self, key: jax.Array, zone_xy: jax.Array, agent_xy: jax.Array) -> dict:
        """Fresh yaws (and Car/Ant joints) per agent, one set of moving-zone directions and
        phases, as the single-agent world draws them."""
        zones = jnp.broadcast_to(zone_xy, (self.num_agents, *zone_xy.shape))
        xy = jnp.concatenate([agent_xy[:, None, :], zones], axis=1)
        per_agent = jax.vmap(self.world._random_layout)(jax.random.split(key, self.num_agents), xy)
        return {k: v if k in AGENT_KEYS else v[0] for k, v in per_agent.items()}

    def reset_to(
        self, key: jax.Array, layout: dict[str, Any], params: MultiZoneParams
    ) -> tuple[Obs, MultiZoneState]:
        """Start an episode from `layout` (as returned by `layout`); `key` is unused."""
        del params
        layout = {k: jnp.asarray(v) for k, v in layout.items()}
        axes = {k: 0 if k in AGENT_KEYS else None for k in layout}
        reset_one = lambda lay: self.world.reset_to(key, lay, self.world.default_params)
        obs, agents = jax.vmap(reset_one, in_axes=(axes,))(layout)
        state = MultiZoneState(
            agents=agents,
            terminated=jnp.zeros(self.num_agents, bool),
            time=jnp.zeros((), jnp.int32),
        )
        return self._observe(obs, agents), state

    # ---- step ---------------------------------------------------------------------------
    def step_env(
        self, key: jax.Array, state: MultiZoneState, action: jax.Array, params: MultiZoneParams
    ) -> tuple[Obs, MultiZoneState, jax.Array, jax.Array, Info]:
        action = jnp.where(state.terminated[:, None], 0.0, action)
        step_one = lambda s, a: self.world.step_env(key, s, a, self.world.default_params)
        obs, agents, _, left, info = jax.vmap(step_one)(state.agents, action)
        terminated = state.terminated | left | self._collided(agents, params)
        state = state.replace(agents=agents, terminated=terminated, time=state.time + 1)
        labels = info["propositions"]  # [N, P]
        info = {"propositions": labels.reshape(-1), "symbol": self._symbol(labels)}
        reward = jnp.zeros(self.num_agents, jnp.float32)
        return self._observe(obs, agents), state, reward, terminated, info

    def _collided(self, agents: ZoneState, params: MultiZoneParams) -> jax.Array:
        """bool[N]: another agent's centre within `collision_distance` (planar), if enabled."""
        xy = agents.physics.agent_pos[:, :2]
        dist = jnp.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
        near = (dist <= params.collision_distance) & ~jnp.eye(self.num_agents, dtype=bool)
        return jnp.any(near, axis=1) & params.collisions

    def _symbol(self, labels: jax.Array) -> jax.Array:
        """int32[]: the row of `alphabet` equal to the joint label (`labels bool[N, P]`)."""
        num_props = labels.shape[1]
        if self._base == 2**num_props:  # every subset: row = bits, proposition 0 lowest
            code = jnp.sum(labels.astype(jnp.int32) << jnp.arange(num_props), axis=1)
        else:  # none or one: row 0 nothing, row p + 1 proposition p
            code = jnp.where(labels.any(axis=1), jnp.argmax(labels, axis=1) + 1, 0)
        weights = self._base ** np.arange(self.num_agents - 1, -1, -1)
        return jnp.sum(code * jnp.asarray(weights, jnp.int32)).astype(jnp.int32)

    def label(self, state: MultiZoneState) -> jax.Array:
        """bool[N * P]: the joint propositions that hold in `state` (as `info["propositions"]`)."""
        return jax.vmap(self.world._labels)(state.agents).reshape(-1)

    def episode_done(self, terminated: jax.Array, truncated: jax.Array) -> jax.Array:
        """bool[]: the world's episode is over (every agent terminated or truncated)."""
        return jnp.all(terminated | truncated, axis=-1)

    def _observe(self, obs: Obs, agents: ZoneState) -> Obs:
        physics = agents.physics
        others_xy = physics.agent_pos[self._others, :2]  # [N, N - 1, 2]
        mask = jnp.ones((1, self.num_agents - 1), bool)
        others = jax.vmap(compute_lidar, in_axes=(0, 0, 0, None, None, None))(
            physics.agent_pos, physics.agent_mat, others_xy, mask,
            self.config.zone_config.num_bins, self.config.partial,
        )
        return {"ap": obs["ap"], "ego": obs["ego"], "others": others.astype(jnp.float32)}

    # ---- the JaxMARL view ---------------------------------------------------------------
    def agent_obs(self, obs: Obs) -> dict[str, Obs]:
        """Per-agent dicts `{"agent_i": {"ap": [P, 16], "ego": [E], "others": [1, 16]}}` of a
        stacked observation (leading batch axes kept)."""
        axis = {k: jnp.ndim(v) - len(self.observation_space[k].shape) for k, v in obs.items()}
        return {
            name: {k: jnp.take(v, i, axis=axis[k]) for k, v in obs.items()}
            for i, name in enumerate(self.agents)
        }

    def stack_actions(self, actions: dict[str, jax.Array]) -> jax.Array:
        """`{"agent_i": float32[A]}` -> `float32[N, A]` in `env.agents` order."""
        if set(actions) != set(self.agents):
            raise ValueError(f"actions for agents {sorted(actions)}; expected {list(self.agents)}")
        return jnp.stack([jnp.asarray(actions[name]) for name in self.agents], axis=-2)

    # ---- layout -------------------------------------------------------------------------
    def layout(self, state: MultiZoneState) -> dict[str, jax.Array]:
        """The episode's start: `agent_xy float32[N, 2]`, `agent_yaw float32[N]` (and for Car
        and Ant `joint_qpos float32[N, J]`), and the zones as in `ZoneEnv.layout`
        (`zone_xy [Z, 2]`, `zone_color`, `zone_radius`, `zone_direction`, `zone_phase`)."""
        per_agent = jax.vmap(self.world.layout)(state.agents)
        return {k: v if k in AGENT_KEYS else v[0] for k, v in per_agent.items()}

    # ---- the original's dict observation (Gymnasium bridge) ----------------------------
    @functools.cached_property
    def _original_layout(self) -> OriginalLayout:
        return OriginalLayout(self)

    @property
    def original_observation_space(self) -> gymnasium.spaces.Dict:
        """The original's observation: `{"agent_i": {"accelerometer_i": ..., ...}}`."""
        return self._original_layout.space()

    def original_observation(self, obs: Obs) -> dict[str, dict[str, np.ndarray]]:
        """One world's stacked `obs` as the original's per-agent dicts (numpy, on the host)."""
        return self._original_layout(obs)
