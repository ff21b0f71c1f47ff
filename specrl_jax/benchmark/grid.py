"""The paper's experiment grid as data: one `Cell` per (world, method, settings), in the order
the project fills it, with an estimate of each cell's GPU time.

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


# ---------------------------------------------------------------------------------------------
# Estimated GPU time
#
# Training: `seeds x total_steps / rate`, with `rate` the aggregate env-steps/s of the seeds
# trained side by side on one GPU, measured on the project's reproduction runs (H100 / H200,
# 5 seeds x 15M, the `env_steps_per_s` of their training summaries, now in the store). A cell
# with no measured run: the rate of GenZ-LTL on its world (or, where none was trained, the
# world's measured auto-reset env-steps/s times TRAIN_PER_ENV_STEP, the ratio of GenZ-LTL's
# training rate to the env's rate measured on PointLTL0 (508,832 / 3.32M = 0.153) and CarLTL0
# (181,242 / 1.10M = 0.165)), times the method's PointLTL0 rate relative to GenZ-LTL's.
# Evaluation: the measured wall time of a cell's suites, else EVAL_S_DEFAULT.

#: (env ID, method[+variant]) -> measured aggregate training env-steps/s, and where
TRAIN_RATES: dict[tuple[str, str], tuple[float, str]] = {
    ("LetterLTL0-v0", "genz"): (543_833, "H100, 5 x 15M"),
    ("LetterLTL0-v0", "deepltl"): (549_551, "H100, 5 x 15M"),
    ("LetterLTL0-v0", "gcrl"): (392_761, "H100, 5 x 15M"),
    ("LetterLTL0-v0", "ltl2action"): (170_381, "H200, 5 x 15M"),
    ("LetterLTL0-v0", "ltl2action+bootcamp"): (168_794, "H200, 5 x 15M"),
    ("LetterLTL0-v0", "rad"): (1_518_550, "H200, 5 x 15M"),
    ("PointLTL0-v0", "genz"): (705_828, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL0-v0", "deepltl"): (467_914, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL0-v0", "gcrl"): (549_097, "H200, 5 x 15M, compile included"),
    ("PointLTL0-v0", "ltl2action"): (537_808, "H200, 5 x 15M, compile included"),
    ("PointLTL0-v0", "ltl2action+bootcamp"): (557_992, "H200, 5 x 15M, compile and a resume included"),
    ("PointLTL0-v0", "rad"): (696_040, "H200, 5 x 15M"),
    ("PointLTL1-v0", "genz"): (735_960, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL1-v0", "deepltl"): (512_933, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL1-v0", "gcrl"): (510_165, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL1-v0", "ltl2action"): (508_620, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL2-v0", "genz"): (741_477, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL2-v0", "deepltl"): (523_278, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL2-v0", "gcrl"): (586_038, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL2-v0", "ltl2action"): (534_798, "H200, 5 x 15M, bank resets, compile included"),
    ("PointLTL2-v0", "rad"): (738_760, "H200, 5 x 15M, bank resets"),
    ("CarLTL0-v0", "genz"): (192_206, "H200, 5 x 15M, MuJoCo Warp, compile included"),
    ("CarLTL0-v0", "deepltl"): (164_226, "H200, 5 x 15M, MuJoCo Warp, compile included"),
    ("CarLTL0-v0", "rad"): (94_063, "H200, 5 x 15M, MJX-JAX (no MuJoCo Warp), a resume included"),
    ("PandaLTLReach0Joints-v0", "genz"): (119_395, ("H200, 5 x 15M, 4,096 x 16 per seed, "
                                                    "compile and a resume included")),
    ("PandaLTLReach0Joints-v0", "deepltl"): (79_113, "H200, 5 x 15M, compile and a resume included"),
    ("PandaLTLReach0Joints-v0", "gcrl"): (178_630, "H200, 5 x 15M, compile included"),
    ("PandaLTLReach0Joints-v0", "ltl2action"): (108_990, "H200, 5 x 15M, compile and two resumes included"),
    ("PandaLTLReach0Joints-v0", "rad"): (113_980, "H200, 5 x 15M, compile and a resume included"),
    ("PointLTL0Vision-v0", "genz"): (68_361, "H200, 5 x 15M at 64 x 64, compile and two resumes included"),
    ("PointLTL0Vision-v0", "deepltl"): (66_080, (
        "H200, 5 x 15M at 64 x 64 learning in turn, convolutions in bfloat16, compile and two "
        "resumes included (70,281 after compilation; float32 55,900)")),
}
#: env ID (without variant suffix) -> measured auto-reset env-steps/s on one GPU, best batch
ENV_RATES: dict[str, tuple[float, str]] = {
    "PointLTL0-v0": (3_320_000, "H100, batch 262,144, exact resets"),
    "PointLTL1-v0": (3_320_000, "as PointLTL0 (training resets from the layout bank: 10.9M)"),
    "PointLTL2-v0": (3_320_000, "as PointLTL0 (training resets from the layout bank: 10.9M)"),
    "CarLTL0-v0": (1_098_525, "H200, batch 262,144, MuJoCo Warp"),
    "AntLTL0-v0": (300_845, "H200, batch 262,144, MuJoCo Warp"),
    "PandaLTLReach0Joints-v0": (575_254, "H200, batch 262,144, bank resets"),
    "PandaLTLReach1Joints-v0": (356_065, "H200, batch 131,072, bank resets"),
}
TRAIN_PER_ENV_STEP = 0.16
#: image worlds: the Point camera world's measured training rate plus the robot's extra physics
#: time per env step. The image pipeline bounds these loops, so a method without GenZ-LTL's KL
#: stop of the epochs trains at DeepLTL's rate (every epoch), whatever its rate on lidar.
VISION_BASE = "PointLTL0Vision-v0"
#: measured evaluation wall time of a cell's suites, 5 seeds x 100 episodes, compile included
#: where it followed the training (the image world's: DeepLTL's cell, its evaluator compiled
#: beside the training; GenZ-LTL's earlier cell took 423 s with the convolution it had then).
#: Another robot's image world adds its LiDAR world's evaluation time over Point's.
EVAL_S: dict[str, float] = {"LetterLTL0-v0": 48.0, "PointLTL0-v0": 42.0, "PointLTL1-v0": 53.0,
                            "PointLTL2-v0": 48.0, "CarLTL0-v0": 160.0, "PointLTL0MA2-v0": 60.0,
                            "PandaLTLReach0Joints-v0": 351.0, VISION_BASE: 82.0}
EVAL_S_DEFAULT = 200.0
SETUP_S = 60.0  # compile and setup per cell


def _base_env(env_id: str) -> str:
    return env_id.split(".")[0]


def _method_factor(key: str) -> float:
    """A method's training rate over GenZ-LTL's: from the PointLTL2 cells (all trained with bank
    resets on one device), else from PointLTL0's."""
    for env in ("PointLTL2-v0", "PointLTL0-v0"):
        rates = {m: r for (e, m), (r, _) in TRAIN_RATES.items() if e == env}
        rate = rates.get(key, rates.get(key.split("+")[0]))
        if rate is not None:
            return rate / rates["genz"]
    return 1.0


def training_rate(c: Cell) -> float:
    """Estimated aggregate training env-steps/s of `c` on one GPU (see above)."""
    key = c.name.split("/", 1)[1]
    env = _base_env(c.env_id)
    if (env, key) in TRAIN_RATES:
        return TRAIN_RATES[(env, key)][0]
    if "Vision" in env:
        base = TRAIN_RATES.get((VISION_BASE, key), TRAIN_RATES[(VISION_BASE, "deepltl")])[0]
        point = ENV_RATES["PointLTL0-v0"][0]
        physics = 1 / ENV_RATES.get(env.replace("Vision", ""), (point,))[0] - 1 / point
        return 1 / (1 / base + physics)
    if (env, "genz") in TRAIN_RATES:
        return TRAIN_RATES[(env, "genz")][0] * _method_factor(key)
    rate = ENV_RATES.get(env, ENV_RATES["PointLTL0-v0"])[0] * TRAIN_PER_ENV_STEP
    return rate * _method_factor(key)


def estimate_seconds(c: Cell) -> float:
    """Estimated GPU seconds of `c` from scratch: training, setup and evaluation."""
    env = _base_env(c.env_id)
    if env in EVAL_S:
        evaluation = EVAL_S[env]
    elif "Vision" in env:
        physics = EVAL_S.get(env.replace("Vision", ""), EVAL_S_DEFAULT) - EVAL_S["PointLTL0-v0"]
        evaluation = EVAL_S[VISION_BASE] + physics
    else:
        evaluation = EVAL_S_DEFAULT
    if not c.trains:
        return evaluation
    return c.seeds * c.total_steps / training_rate(c) + SETUP_S + evaluation
