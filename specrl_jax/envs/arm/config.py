"""The frozen configuration of an Arm world, validated at the Python boundary."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: colours a custom arm may use (each is a proposition name or part of one)
COLOR_NAMES = ("magenta", "yellow", "blue", "green", "red", "cyan", "orange", "purple")
#: the benchmark's colours in the original's placement order
BENCHMARK_COLORS = ("magenta", "yellow", "blue", "green")
#: the original's region-centre sampling box, metres; z runs over [r, r + 0.5]
BOX_LOW = (-0.5, -0.3)
BOX_HIGH = (0.2, 0.3)
BOX_HEIGHT = 0.5
#: action kinds: joint-target deltas (the `...Joints` IDs) or end-effector displacements
CONTROLS = ("joints", "ee")
#: how the physics runs its motor solve (`physics.motor_torque`'s `solve`)
MOTOR_SOLVES = ("auto", "xla", "pallas", "pallas_interpret")


@dataclass(frozen=True)
class ArmConfig:
    """Static settings of an Arm world (everything that fixes shapes or compiled code).

    Attributes:
        mode: 0 "grippers-only" (propositions `<colour>`: grasp target inside a region) or
            1 "grippers+arm" (`arm_<colour>`, `grippers_<colour>`: link contact).
        partial: linear 0.25 m distance features instead of `exp(-2 d)`.
        control: "joints" (action float[7]: joint targets q + 0.05 a) or "ee" (action float[3]:
            grasp-target displacement 0.05 a, metres, through PyBullet's IK; `arm/ik.py`).
        colors: region colours in placement order.
        regions_per_color: regions of each colour.
        region_radius: sphere radius, metres.
        keepout: minimum gap between regions and between a region and the robot's neutral pose
            (its hulls), metres.
        horizon: default `params.max_steps`.
        max_tries: tries per region before a layout restart (original: 100).
        layouts_per_round: whole candidate layouts drawn per loop iteration of the exact
            sampler (a speed/memory knob only; the distribution does not depend on it).
        exact_checks_per_round: exact hull-distance keep-out tests per round, for centres the
            precomputed keep-out grid cannot settle (speed only; at least `num_regions`).
        continuation_slots: candidates per round and region that may draw tries beyond the
            first 8 (speed only; `layout.place_round`).
        max_rounds: loop iterations before the sampler gives up (returns the neutral-arm
            layout of its last candidate; `layout_ok` in the state says so).
        table_contacts: whether the arm collides with the table and floor (the original's).
        motor_solve: how the physics runs its motor solve each substep (speed only):
            "auto" (the Pallas kernel on a GPU, jnp operations elsewhere), "xla" (jnp
            operations), "pallas" (one Pallas kernel per arm, a GPU) or "pallas_interpret"
            (that kernel in Pallas' interpreter).
    """

    mode: int = 0
    partial: bool = False
    control: str = "joints"
    colors: tuple[str, ...] = BENCHMARK_COLORS
    regions_per_color: int = 2
    region_radius: float = 0.06
    keepout: float = 0.08
    horizon: int = 200
    max_tries: int = 100
    layouts_per_round: int = 512
    exact_checks_per_round: int = 16
    continuation_slots: int = 8
    max_rounds: int = 400
    table_contacts: bool = True
    motor_solve: str = "auto"

    def __post_init__(self) -> None:
        if self.mode not in (0, 1) or isinstance(self.mode, bool):
            raise ValueError(f"mode must be 0 (grippers-only) or 1 (grippers+arm), got {self.mode!r}")
        if self.control not in CONTROLS:
            raise ValueError(f"control must be one of {CONTROLS}, got {self.control!r}")
        if self.motor_solve not in MOTOR_SOLVES:
            raise ValueError(f"motor_solve must be one of {MOTOR_SOLVES}, got {self.motor_solve!r}")
        colors = tuple(self.colors) if isinstance(self.colors, (list, tuple)) else ()
        if not colors or len(set(colors)) != len(colors) or any(c not in COLOR_NAMES for c in colors):
            raise ValueError(f"colors must be distinct names from {COLOR_NAMES}; got {self.colors!r}")
        object.__setattr__(self, "colors", colors)
        if not isinstance(self.regions_per_color, int) or self.regions_per_color < 1:
            raise ValueError(f"regions_per_color must be a positive int, got {self.regions_per_color!r}")
        if not 0 < self.region_radius <= 0.25:
            raise ValueError(f"region_radius must be in (0, 0.25] m, got {self.region_radius!r}")
        if self.keepout < 0:
            raise ValueError(f"keepout must be >= 0 m, got {self.keepout!r}")
        if not isinstance(self.horizon, int) or self.horizon < 1:
            raise ValueError(f"horizon must be a positive int, got {self.horizon!r}")
        for name in ("max_tries", "layouts_per_round", "max_rounds", "continuation_slots"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive int, got {getattr(self, name)!r}")
        # Spheres of diameter keepout + 2r around each centre must not overlap: a loose packing
        # bound (74% of the box grown by half a separation) rejects clearly impossible configs.
        sep = self.keepout + 2 * self.region_radius
        grown = [h - l + sep for l, h in zip(BOX_LOW, BOX_HIGH)] + [BOX_HEIGHT + sep]
        need = self.num_regions * math.pi / 6 * sep**3
        if need > 0.74 * math.prod(grown):
            raise ValueError(
                f"{self.num_regions} regions {sep:.2f} m apart (keepout {self.keepout} + 2 x radius "
                f"{self.region_radius}) cannot fit in the sampling box "
                f"{BOX_LOW}-{BOX_HIGH} x {BOX_HEIGHT} m high; use fewer or smaller regions"
            )
        checks = self.exact_checks_per_round
        if not isinstance(checks, int) or checks < self.num_regions:
            raise ValueError(
                f"exact_checks_per_round must be an int >= the number of regions "
                f"({self.num_regions}), got {checks!r}"
            )

    @property
    def num_regions(self) -> int:
        return self.regions_per_color * len(self.colors)

    @property
    def propositions(self) -> tuple[str, ...]:
        """Sorted names: colours (mode 0), or `arm_<c>` then `grippers_<c>` (mode 1)."""
        if self.mode == 0:
            return tuple(sorted(self.colors))
        return tuple(sorted(f"{part}_{c}" for part in ("arm", "grippers") for c in self.colors))

    @property
    def same_object(self) -> tuple[tuple[str, str], ...]:
        """Propositions that name one sphere (mode 1: `arm_<c>` and `grippers_<c>`; the hand is
        an arm link, so it usually touches what the fingers reach); none in mode 0."""
        return () if self.mode == 0 else tuple((f"arm_{c}", f"grippers_{c}") for c in sorted(self.colors))


__all__ = ["BENCHMARK_COLORS", "COLOR_NAMES", "CONTROLS", "ArmConfig"]
