"""The frozen configuration of a Zone world, with its validation at the Python boundary."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from specrl_jax.envs.zone.models import ROBOTS, Solver
from specrl_jax.envs.zone.motion import MOTIONS
from specrl_jax.envs.zone.physics import PHYSICS

#: The 16 colour names the original accepts for custom worlds.
COLOR_NAMES = (
    "black", "blue", "green", "cyan", "red", "magenta", "yellow", "white",
    "orange", "purple", "lime", "teal", "pink", "brown", "navy", "gray",
)
#: The benchmark's colours, in the original's placement order.
BENCHMARK_COLORS = ("green", "yellow", "blue", "magenta")
#: Zone keepout of the benchmark levels (normal variants); overlap variants use radius / 2.
LEVEL_KEEPOUT = {0: 0.55, 1: 0.65, 2: 0.70}
#: Solver settings per robot (see `docs/fidelity.md` and tests/envs/test_zone_physics.py).
DEFAULT_SOLVERS = {
    "Point": Solver(iterations=1, ls_iterations=4, condim=6),  # no contacts: nothing to solve
    # Line search capped at 4: MuJoCo C trajectories move by < 1e-6 m (tested), MJX-JAX runs
    # 31% (Car) and 61% (Ant) faster on an H100 (docs/fidelity.md). At most 5 (Car) / 4
    # (Ant) contacts reach the solver: no more ever penetrate at once in MuJoCo C rollouts of a
    # live robot (tested), so only constraint rows that stay empty are dropped (fidelity.md,
    # Zone physics, "Solver rows (MJX-JAX)").
    "Car": Solver(iterations=10, ls_iterations=4, condim=6, max_contacts=5),
    "Ant": Solver(iterations=8, ls_iterations=4, condim=6, max_contacts=4),
}


def _is_number(value, kind: type) -> bool:
    """An int (for `kind` int), or a finite int or float (for `kind` float); never a bool."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return isinstance(value, int) if kind is int else math.isfinite(value)


def _per_color(value, colors: tuple[str, ...], name: str, kind: type) -> tuple:
    if _is_number(value, kind):
        return tuple(kind(value) for _ in colors)
    if (
        isinstance(value, (tuple, list)) and len(value) == len(colors)
        and all(_is_number(v, kind) for v in value)
    ):
        return tuple(kind(v) for v in value)
    raise ValueError(
        f"{name} must be one {kind.__name__} or a sequence with one per colour "
        f"({len(colors)} colours: {colors}); got {value!r}"
    )


def _image_size(value) -> tuple[int, int]:
    size = (value, value) if isinstance(value, int) and not isinstance(value, bool) else value
    if (
        not isinstance(size, (tuple, list)) or len(size) != 2
        or not all(isinstance(n, int) and not isinstance(n, bool) and 32 <= n <= 1024 for n in size)
    ):
        raise ValueError(
            f"image_size must be an int or (height, width) of ints in 32..1024; got {value!r}"
        )
    return tuple(size)


@dataclass(frozen=True)
class ZoneConfig:
    """Static settings of a Zone world (everything that fixes shapes or compiled code).

    Attributes:
        robot: "Point", "Car" or "Ant".
        colors: zone colours in placement order (names from `COLOR_NAMES`).
        zones_per_color: zones of each colour (int, or one per colour).
        zone_radius: zone radius per colour, metres (labels and sampling).
        moving_per_color: how many zones of each colour move (the first ones of that colour).
        zone_keepout: layout keepout of each colour's zones, metres.
        agent_keepout: layout keepout of the agent, metres (None: the robot's, 0.4).
        extent: half-size of the placement square, metres (objects are placed inside
            [-extent + keepout, extent - keepout]^2).
        partial: linear 1.2 m LiDAR instead of the exponential one.
        overlap_alphabet: declare every subset of propositions as possible (the `.overlap`
            variants); when False the alphabet is still widened if the geometry lets
            zones of different colours overlap.
        horizon: default `params.max_steps`.
        solver: physics solver settings (None: the robot's default).
        physics: "auto" (default: MuJoCo Warp for Car and Ant on one CUDA GPU with warp-lang
            installed, MJX's JAX implementation otherwise; `physics.resolve_physics`), "jax"
            (MJX's JAX implementation, any device) or "warp" (MuJoCo Warp through MJX; needs
            warp-lang and a CUDA GPU, or a CPU where warp-lang can compile).
        wall: |x| or |y| at which the episode terminates, metres.
        travel: radius of a moving zone's commanded circle, metres.
        angular_speed: of a moving zone's command, rad per simulated second.
        zone_motion: "weld" (the original's: the zone is dragged after its circular command
            by a soft weld, starting from its layout centre; `motion.py`) or "circle" (the
            zone is on the commanded circle from t = 0).
        max_tries: tries per object before a layout restart (original: 100).
        max_restarts: whole-layout attempts before giving up (original: 10000).
        vision: add the robot camera's frame `obs["image"]`, uint8[H, W, 3] (the `Vision` IDs;
            `camera.py`).
        image_size: `(H, W)` of that frame in pixels, each 32 to 1024 (an int: square); the
            original's is 256 x 256.
    """

    robot: str = "Point"
    colors: tuple[str, ...] = BENCHMARK_COLORS
    zones_per_color: int | tuple[int, ...] = 2
    zone_radius: float | tuple[float, ...] = 0.4
    moving_per_color: int | tuple[int, ...] = 0
    zone_keepout: float | tuple[float, ...] = LEVEL_KEEPOUT[0]
    agent_keepout: float | None = None
    extent: float = 2.5
    partial: bool = False
    overlap_alphabet: bool = False
    horizon: int = 1000
    solver: Solver | None = None
    physics: str = "auto"
    wall: float = 3.3
    travel: float = 0.3
    angular_speed: float = 2.0
    zone_motion: str = "weld"
    max_tries: int = 100
    max_restarts: int = 10000
    vision: bool = False
    image_size: int | tuple[int, int] = 256
    num_bins: int = field(default=16, init=False)

    def __post_init__(self) -> None:
        if self.physics not in PHYSICS:
            raise ValueError(f"unknown physics backend {self.physics!r}; accepted: {PHYSICS}")
        if self.zone_motion not in MOTIONS:
            raise ValueError(f"unknown zone_motion {self.zone_motion!r}; accepted: {MOTIONS}")
        if self.robot not in ROBOTS:
            raise ValueError(f"unknown robot {self.robot!r}; accepted: {tuple(ROBOTS)}")
        colors = tuple(self.colors) if isinstance(self.colors, (list, tuple)) else None
        if not colors:
            raise ValueError(f"colors must be a non-empty sequence of names; got {self.colors!r}")
        unknown = [c for c in colors if c not in COLOR_NAMES]
        if unknown or len(set(colors)) != len(colors):
            raise ValueError(
                f"colors must be distinct names from {COLOR_NAMES}; got {colors!r}"
            )
        set_ = lambda name, value: object.__setattr__(self, name, value)
        set_("colors", colors)
        set_("zones_per_color", _per_color(self.zones_per_color, colors, "zones_per_color", int))
        set_("zone_radius", _per_color(self.zone_radius, colors, "zone_radius", float))
        set_("moving_per_color", _per_color(self.moving_per_color, colors, "moving_per_color", int))
        set_("zone_keepout", _per_color(self.zone_keepout, colors, "zone_keepout", float))
        if self.agent_keepout is None:
            set_("agent_keepout", ROBOTS[self.robot].keepout)
        if self.solver is None:
            set_("solver", DEFAULT_SOLVERS[self.robot])
        self._check_numbers()
        set_("image_size", _image_size(self.image_size))

    def _check_numbers(self) -> None:
        for name, kind in (("extent", float), ("wall", float), ("travel", float),
                           ("angular_speed", float), ("agent_keepout", float),
                           ("max_tries", int), ("max_restarts", int)):
            if not _is_number(getattr(self, name), kind):
                what = "an int" if kind is int else "a finite number"
                raise ValueError(f"{name} must be {what}, got {getattr(self, name)!r}")
        if self.travel < 0:
            raise ValueError(f"travel must be >= 0 metres, got {self.travel}")
        for c, n, m, r, k in zip(
            self.colors, self.zones_per_color, self.moving_per_color, self.zone_radius,
            self.zone_keepout,
        ):
            if n < 0 or not 0 <= m <= n:
                raise ValueError(
                    f"colour {c!r}: need 0 <= moving_per_color <= zones_per_color, got "
                    f"{m} moving of {n} zones"
                )
            if r <= 0 or k < 0:
                raise ValueError(f"colour {c!r}: zone_radius must be > 0 and keepout >= 0, got {r}, {k}")
            if n and k >= self.extent:
                raise ValueError(
                    f"colour {c!r}: zone keepout {k} leaves no room to place it inside the "
                    f"extent {self.extent} (need keepout < extent)"
                )
            reach = self.extent - k + (self.travel if m else 0.0)  # farthest centre from 0
            if n and r + reach > self.wall + 1e-9:
                moving = f" plus travel {self.travel}" if m else ""
                raise ValueError(
                    f"colour {c!r}: zones of radius {r} m cross the walls (the arena is "
                    f"+-{self.wall} m): the layout sampler puts a centre up to extent - keepout "
                    f"= {self.extent - k:.2f} m{moving} from the middle, so zone_radius must be "
                    f"<= {self.wall - reach:.2f} m (wall - {reach:.2f}); use a smaller "
                    "zone_radius, a larger zone_keepout or a smaller extent"
                )
        if self.num_zones < 1:
            raise ValueError("a Zone world needs at least one zone")
        if not 0 <= self.agent_keepout < self.extent:
            raise ValueError(f"agent_keepout must be in [0, extent={self.extent}), got {self.agent_keepout}")
        if self.extent <= 0 or self.wall <= self.extent:
            raise ValueError(
                f"need 0 < extent < wall so that the agent starts inside the walls; got "
                f"extent={self.extent}, wall={self.wall}"
            )
        if not isinstance(self.horizon, int) or self.horizon < 1:
            raise ValueError(f"horizon must be a positive int, got {self.horizon!r}")
        if self.max_tries < 1 or self.max_restarts < 1:
            raise ValueError("max_tries and max_restarts must be >= 1")
        placed_area = sum(
            n * math.pi * k * k for n, k in zip(self.zones_per_color, self.zone_keepout)
        ) + math.pi * self.agent_keepout**2
        if placed_area > (2 * self.extent) ** 2 * 0.9069:  # densest disc packing
            raise ValueError(
                f"the keepout discs cover {placed_area:.2f} m^2, more than can be packed into "
                f"the {2 * self.extent:.1f} m square; use fewer or smaller zones"
            )

    @property
    def num_zones(self) -> int:
        return sum(self.zones_per_color)

    @property
    def propositions(self) -> tuple[str, ...]:
        """Colour names sorted alphabetically (the original's `get_propositions()`)."""
        return tuple(sorted(self.colors))

    @property
    def has_moving_zones(self) -> bool:
        return sum(self.moving_per_color) > 0


def level_config(robot: str, level: int, partial: bool = False, overlap: bool = False, **kw) -> ZoneConfig:
    """The config of `{robot}LTL{level}-v0[.partial|.overlap|.partial_overlap]`."""
    if level not in LEVEL_KEEPOUT:
        raise ValueError(f"level must be 0, 1 or 2, got {level!r}")
    keepout = 0.2 if overlap else LEVEL_KEEPOUT[level]
    return ZoneConfig(
        robot=robot, zone_keepout=keepout, moving_per_color=min(level, 2), partial=partial,
        overlap_alphabet=overlap, **kw,
    )
