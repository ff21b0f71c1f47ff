"""The frozen configuration of a multi-agent Zone world, validated at the Python boundary."""

from __future__ import annotations

import math
from dataclasses import dataclass

from specrl_jax.envs.zone.config import BENCHMARK_COLORS, ZoneConfig
from specrl_jax.envs.zone.models import Solver

#: The original multi-agent world (`PointLTL0MA3-v0`): zone radius, zone and agent keepouts.
MA_ZONE_RADIUS = 0.5
MA_ZONE_KEEPOUT = 0.65
MA_AGENT_KEEPOUT = 0.55
#: Planar centre distance at which the original counts two agents as colliding, metres.
MA_COLLISION_DISTANCE = 0.28


@dataclass(frozen=True)
class MultiZoneConfig:
    """Static settings of a multi-agent Zone world: N robots of one kind among coloured zones.

    Attributes:
        num_agents: N, the number of robots.
        robot: "Point" (the original's only multi-agent robot), "Car" or "Ant".
        colors: zone colours in placement order (names from `zone.config.COLOR_NAMES`).
        zones_per_color, zone_radius, zone_keepout, moving_per_color: per colour, as in
            `ZoneConfig` (the original: 2 static zones of radius 0.5, keepout 0.65).
        agent_keepout: layout keepout of each agent, metres; agents are placed at least
            2 x this apart (the original: 0.55, so 1.1 m).
        agent_zone_gap: extra clearance of an agent from a zone centre beyond the zone's keepout,
            metres. The original as run keeps agents only `zone_keepout` (0.65) from zone centres,
            its code intends `zone_keepout + agent_keepout` (1.2): 0.0 is the former, 0.55 the
            latter (docs/fidelity.md, "multi-agent zone: agent placement").
        extent: half-size of the placement square, metres.
        partial: linear 1.2 m LiDAR (zones and other agents) instead of `exp(-0.5 d)`.
        overlap_alphabet: every subset of colours per agent in the alphabet.
        horizon: default `params.max_steps` (the original: 1000).
        collisions: an agent terminates when another agent's body is within
            `collision_distance` (planar, centres), as the original's code does; off by
            default, as in the paper's evaluation (docs/fidelity.md).
        collision_distance: metres.
        solver, physics, wall: as in `ZoneConfig`, but physics defaults to "jax" (agents under
            MuJoCo Warp are not measured).
        max_tries: tries per object before a layout restart (the original's multi-agent
            sampler: 1000).
        max_restarts: whole-layout attempts before giving up (original: 10000).
    """

    num_agents: int = 3
    robot: str = "Point"
    colors: tuple[str, ...] = BENCHMARK_COLORS
    zones_per_color: int | tuple[int, ...] = 2
    zone_radius: float | tuple[float, ...] = MA_ZONE_RADIUS
    zone_keepout: float | tuple[float, ...] = MA_ZONE_KEEPOUT
    moving_per_color: int | tuple[int, ...] = 0
    agent_keepout: float = MA_AGENT_KEEPOUT
    agent_zone_gap: float = 0.0
    extent: float = 2.5
    partial: bool = False
    overlap_alphabet: bool = False
    horizon: int = 1000
    collisions: bool = False
    collision_distance: float = MA_COLLISION_DISTANCE
    solver: Solver | None = None
    physics: str = "jax"
    wall: float = 3.3
    max_tries: int = 1000
    max_restarts: int = 10000

    def __post_init__(self) -> None:
        num = self.num_agents
        if not isinstance(num, int) or isinstance(num, bool) or num < 1:
            raise ValueError(f"num_agents must be a positive int, got {self.num_agents!r}")
        if self.agent_zone_gap < 0 or self.collision_distance < 0:
            raise ValueError(
                f"agent_zone_gap and collision_distance must be >= 0, got "
                f"{self.agent_zone_gap} and {self.collision_distance}"
            )
        if not isinstance(self.collisions, bool):
            raise TypeError(f"collisions must be a bool, got {self.collisions!r}")
        zone = self.zone_config  # validates the per-colour fields, robot, physics, extent, ...
        for name in ("colors", "zones_per_color", "zone_radius", "zone_keepout", "moving_per_color",
                     "solver"):
            object.__setattr__(self, name, getattr(zone, name))
        placed = sum(
            n * math.pi * k * k for n, k in zip(self.zones_per_color, self.zone_keepout)
        ) + self.num_agents * math.pi * self.agent_keepout**2
        if placed > (2 * self.extent) ** 2 * 0.9069:  # densest disc packing
            raise ValueError(
                f"{self.num_agents} agents and {zone.num_zones} zones: the keepout discs cover "
                f"{placed:.2f} m^2, more than fits into the {2 * self.extent:.1f} m square; use "
                "fewer agents or zones, or smaller keepouts"
            )

    @property
    def zone_config(self) -> ZoneConfig:
        """The single-agent world each agent sees (its sensors, labels and physics)."""
        return ZoneConfig(
            robot=self.robot, colors=self.colors, zones_per_color=self.zones_per_color,
            zone_radius=self.zone_radius, moving_per_color=self.moving_per_color,
            zone_keepout=self.zone_keepout, agent_keepout=self.agent_keepout, extent=self.extent,
            partial=self.partial, overlap_alphabet=self.overlap_alphabet, horizon=self.horizon,
            solver=self.solver, physics=self.physics, wall=self.wall,
        )  # the single-agent sampler's tries are not used: layout.py places every agent

    @property
    def agents(self) -> tuple[str, ...]:
        """Agent names, `("agent_0", ..., "agent_{N-1}")`."""
        return tuple(f"agent_{i}" for i in range(self.num_agents))

    @property
    def colour_propositions(self) -> tuple[str, ...]:
        """One agent's propositions: the colours, sorted (the single-agent order)."""
        return tuple(sorted(self.colors))

    @property
    def propositions(self) -> tuple[str, ...]:
        """Joint propositions `<colour>_<i>`, agent-major: agent 0's colours, then agent 1's."""
        return tuple(f"{c}_{i}" for i in range(self.num_agents) for c in self.colour_propositions)


def ma_config(num_agents: int, **overrides) -> MultiZoneConfig:
    """The config of `PointLTL0MA{num_agents}-v0` (the original's multi-agent world)."""
    return MultiZoneConfig(num_agents=num_agents, **overrides)
