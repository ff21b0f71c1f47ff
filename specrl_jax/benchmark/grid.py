"""The paper's experiment grid as data: one `Cell` per (world, method, settings), in the order
the project fills it (`benchmark.estimate` says what each costs).

A cell's name is `<env ID>/<method>[+<variant>]`, e.g. `LetterLTL0-v0/genz` or
`LetterLTL0-v0/ltl2action+bootcamp` (LTL2Action from the shipped LTLBootcamp encoder). A cell
trains `seeds` runs of `total_steps` env steps side by side and evaluates every suite of
`suites` with `episodes` episodes per spec and seed. An evaluation-only cell (`params_from`)
deploys another cell's seed-1 parameters, e.g. the multi-agent coordinator cells on
`PointLTL0MA2-v0`, which run the single-agent PointLTL0 policies on every agent.

World settings (horizon, PPO shape and discount, network sizes) belong to the world family and
the method; a cell holds only what differs from them (`ppo`, `method_options`, `env_options`).

    from specrl_jax.benchmark import grid
    grid.select("Point*/genz")      # cells whose name matches the fnmatch pattern
"""

from __future__ import annotations

import dataclasses
import fnmatch
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from specrl_jax import families

METHODS = ("genz", "deepltl", "ltl2action", "gcrl", "rad")
#: methods the paper evaluates on the infinite suites (RAD-Embeddings only on co-safe ones;
#: on the arm the paper's infinite rows are GenZ-LTL, DeepLTL and GCRL-LTL)
INFINITE_METHODS = ("genz", "deepltl", "gcrl")
#: methods deployed on every agent by the multi-agent coordinator
COORDINATOR_METHODS = ("genz", "deepltl", "gcrl")
PACKAGE = Path(__file__).resolve().parents[1]
#: a method option starting with this names a file shipped in the package (resolved at run time)
PACKAGE_FILE = "package:"

# the paper's suites of each world, from the family records
LETTER = families.LETTER.suites
ZONE = families.ZONE.suites
ARM0 = tuple(s for s in families.ARM.suites if s.startswith("arm_grippers/"))
ARM1 = tuple(s for s in families.ARM.suites if s.startswith("arm_grippers_arm/"))
MULTI_AGENT = families.MULTI_AGENT_ZONE.suites

#: the issue's steps, in the order to fill them
STEPS = {
    0: "LetterWorld and PointLTL0, five methods; the multi-agent coordinator (before the grid)",
    1: "Arm, grippers-only (PandaLTLReach0Joints-v0), five methods",
    2: "Robot dynamics: CarLTL0 and AntLTL0 with LiDAR, five methods",
    3: "Partial observability, moving zones, arm modes",
    4: "Image observations: Point, Car and Ant with the paper's CNN",
}


@dataclasses.dataclass(frozen=True)
class Cell:
    """One experiment of the grid (see the module docstring)."""

    env_id: str
    method: str
    variant: str = ""
    suites: tuple[str, ...] = ()
    seeds: int = 5
    total_steps: int = 15_000_000
    episodes: int = 100
    step: int = 0
    method_options: tuple[tuple[str, Any], ...] = ()
    env_options: tuple[tuple[str, Any], ...] = ()
    ppo: tuple[tuple[str, Any], ...] = ()
    params_from: str | None = None  # evaluation-only: the trained cell whose seed-1 params it runs

    @property
    def name(self) -> str:
        return f"{self.env_id}/{self.method}" + (f"+{self.variant}" if self.variant else "")

    @property
    def trains(self) -> bool:
        return self.params_from is None

    def options(self) -> dict[str, Any]:
        """`method_options` with package files resolved to their paths."""
        return {k: resolve(v) for k, v in self.method_options}

    def config(self) -> dict[str, Any]:
        """The cell's settings as JSON-ready data (what `cell.json` records)."""
        return {
            "name": self.name, "env_id": self.env_id, "method": self.method,
            "variant": self.variant, "suites": list(self.suites), "seeds": self.seeds,
            "total_steps": self.total_steps, "episodes": self.episodes, "step": self.step,
            "method_options": dict(self.method_options), "env_options": dict(self.env_options),
            "ppo": dict(self.ppo), "params_from": self.params_from,
        }


def resolve(value: Any) -> Any:
    """`package:<path>` -> the absolute path of that file in the installed package."""
    if isinstance(value, str) and value.startswith(PACKAGE_FILE):
        return str(PACKAGE / value[len(PACKAGE_FILE):])
    return value


def file_name(name: str) -> str:
    """A cell name as a directory name (`/` -> `__`)."""
    return name.replace("/", "__")


def cell_name(file: str) -> str:
    return file.replace("__", "/")


def _suites(method: str, suites: Sequence[str]) -> tuple[str, ...]:
    """The suites a method is evaluated on: RAD-Embeddings the co-safe (finite) ones only."""
    if method == "rad":
        return tuple(s for s in suites if "/finite/" in s)
    return tuple(suites)


def _five(env_id: str, suites: Sequence[str], step: int, **kw: Any) -> list[Cell]:
    return [Cell(env_id, m, suites=_suites(m, suites), step=step, **kw) for m in METHODS]


def _bootcamp(env_id: str, family: str, suites: Sequence[str], step: int) -> Cell:
    """LTL2Action from the shipped LTLBootcamp encoder of `family` (letter / zone)."""
    encoder = f"{PACKAGE_FILE}baselines/data/ltl2action_encoder_{family}.msgpack"
    return Cell(env_id, "ltl2action", "bootcamp", suites=tuple(suites), step=step,
                method_options=(("encoder", encoder),))


#: the image cells' camera: 64 x 64 (the world's default and the original's is 256 x 256; fidelity.md)
VISION_OPTIONS = (("image_size", 64),)
#: the image cells' CNN convolutions in bfloat16 (fidelity.md; PointLTL0Vision GenZ-LTL ran float32)
VISION_METHOD_OPTIONS = (("image_dtype", "bfloat16"),)


def _build() -> tuple[Cell, ...]:
    cells: list[Cell] = []
    # step 0: done before the grid existed (results moved into the store)
    cells += _five("LetterLTL0-v0", LETTER, 0)
    cells.append(_bootcamp("LetterLTL0-v0", "letter", LETTER, 0))
    cells += _five("PointLTL0-v0", ZONE, 0)
    cells.append(_bootcamp("PointLTL0-v0", "zone", ZONE, 0))
    cells += [Cell("PointLTL0MA2-v0", m, "coordinator", suites=MULTI_AGENT, step=0,
                   params_from=f"PointLTL0-v0/{m}") for m in COORDINATOR_METHODS]
    # step 1: the arm, grippers-only
    cells += _five("PandaLTLReach0Joints-v0", ARM0, 1)
    # step 2: robot dynamics with LiDAR
    for robot in ("Car", "Ant"):
        cells += _five(f"{robot}LTL0-v0", ZONE, 2)
    # step 3: partial view, moving zones, the grippers-and-arm mode
    cells += _five("LetterLTL0-v0.partial", LETTER, 3)
    for level in (1, 2):
        cells += _five(f"PointLTL{level}-v0", ZONE, 3)
    cells += _five("PandaLTLReach1Joints-v0", ARM1, 3)
    # step 4: pixels
    for robot in ("Point", "Car", "Ant"):
        cells += _five(f"{robot}LTL0Vision-v0", ZONE, 4, env_options=VISION_OPTIONS,
                       method_options=VISION_METHOD_OPTIONS)
    return tuple(cells)


GRID: tuple[Cell, ...] = _build()
BY_NAME: dict[str, Cell] = {c.name: c for c in GRID}


def cell(name: str) -> Cell:
    if name not in BY_NAME:
        raise ValueError(f"no cell {name!r} in the grid; `specrl-jax reproduce --list` shows them")
    return BY_NAME[name]


def select(patterns: str | Sequence[str] | None = None, cells: Sequence[Cell] = GRID) -> list[Cell]:
    """Cells whose name matches any of the `fnmatch` patterns (comma-separated or a list; None:
    all), in grid order. A pattern matching nothing is an error."""
    if patterns is None:
        return list(cells)
    if isinstance(patterns, str):
        patterns = [p.strip() for p in patterns.split(",") if p.strip()]
    chosen = []
    for pattern in patterns:
        if not any(fnmatch.fnmatchcase(c.name, pattern) for c in cells):
            raise ValueError(f"--cells {pattern!r} matches no cell; `specrl-jax reproduce --list` "
                             "shows them")
    for c in cells:
        if any(fnmatch.fnmatchcase(c.name, p) for p in patterns):
            chosen.append(c)
    return chosen
