"""Estimated GPU time of a grid cell on one GPU, from what the results store measured.

Training takes `seeds x total_steps / rate`, with `rate` the aggregate env-steps/s of the seeds
learning on one GPU (the `env_steps_per_s` of a stored training summary, compilation and
resumes included):

- the cell's own rate, where the store holds its training;
- on an image world, the Point camera world's rate of the method, else of DeepLTL (every method
  but GenZ-LTL runs all its epochs there, so the image pipeline bounds them alike), plus the
  robot's extra physics time per env step over Point's (`ENV_RATES`);
- else GenZ-LTL's rate on the world times the method's rate over GenZ-LTL's on PointLTL2 (else
  PointLTL0), whose cells all trained on one device with bank resets;
- on a world without a trained cell, GenZ-LTL's profiled training rate there (`PROFILED_RATES`)
  times that method factor, else its auto-reset env-steps/s times `TRAIN_PER_ENV_STEP`, the
  ratio of GenZ-LTL's training rate to the env's on PointLTL0 (0.153) and CarLTL0 (0.165).

Evaluation and set-up add `EVAL_S` and `SETUP_S`.
"""

from __future__ import annotations

from collections.abc import Mapping

from specrl_jax.benchmark import grid
from specrl_jax.benchmark.grid import Cell
from specrl_jax.benchmark.store import Store

#: env ID -> measured auto-reset env-steps/s on one GPU, best batch (results.md, Worlds)
ENV_RATES: dict[str, float] = {
    "PointLTL0-v0": 3_320_000,  # H100, batch 262,144, exact resets
    "CarLTL0-v0": 1_098_525,  # H200, batch 262,144, MuJoCo Warp
    "AntLTL0-v0": 300_845,  # H200, batch 262,144, MuJoCo Warp
}
TRAIN_PER_ENV_STEP = 0.16
#: env ID -> GenZ-LTL's profiled training env-steps/s at the grid's shape, 5 seeds on one GPU,
#: for a world the store has not trained on (results.md, Training speed; H200): a steady rate,
#: without the compilation and resumes of a cell's (cells ran about 6% below their steady rate)
PROFILED_RATES: dict[str, float] = {"AntLTL0-v0": 69_794}
VISION_BASE = "PointLTL0Vision-v0"
#: measured evaluation wall time of a cell's suites, 5 seeds x 100 episodes, compilation included
#: where it followed the training (the image world's: DeepLTL's cell, its evaluator compiled
#: beside the training; GenZ-LTL's earlier cell took 423 s with the convolution it had then).
#: Another robot's image world adds its LiDAR world's evaluation time over Point's. Ant's is
#: not measured: 11,000 steps of its suites at its rollout's 36 ms per step, and compilation.
EVAL_S: dict[str, float] = {"LetterLTL0-v0": 48.0, "PointLTL0-v0": 42.0, "PointLTL1-v0": 53.0,
                            "PointLTL2-v0": 48.0, "CarLTL0-v0": 160.0, "AntLTL0-v0": 460.0,
                            "PointLTL0MA2-v0": 60.0, "PandaLTLReach0Joints-v0": 351.0,
                            VISION_BASE: 82.0}
EVAL_S_DEFAULT = 200.0
SETUP_S = 60.0  # compilation and set-up per cell


def measured_rates(store: Store | None = None) -> dict[str, float]:
    """{cell name: aggregate training env-steps/s} of every trained cell of `store` (default:
    the package's results store)."""
    store = store or Store()
    rates = {}
    for c in grid.GRID:
        record = store.read(c)
        rate = (record or {}).get("training", {}).get("env_steps_per_s")
        if rate:
            rates[c.name] = float(rate)
    return rates


def _env(env_id: str) -> str:
    return env_id.split(".")[0]


def _method_factor(key: str, rates: Mapping[str, float]) -> float:
    """A method's training rate over GenZ-LTL's on PointLTL2, else PointLTL0; 1 without both."""
    for env in ("PointLTL2-v0", "PointLTL0-v0"):
        rate = rates.get(f"{env}/{key}", rates.get(f"{env}/{key.split('+')[0]}"))
        if rate is not None and f"{env}/genz" in rates:
            return rate / rates[f"{env}/genz"]
    return 1.0


def training_rate(c: Cell, rates: Mapping[str, float] | None = None) -> float:
    """Estimated aggregate training env-steps/s of `c` on one GPU (`rates`: `measured_rates()`)."""
    rates = measured_rates() if rates is None else rates
    if c.name in rates:
        return rates[c.name]
    key, env = c.name.split("/", 1)[1], _env(c.env_id)
    if "Vision" in env:
        base = rates.get(f"{VISION_BASE}/{key}", rates.get(f"{VISION_BASE}/deepltl"))
        if base is not None:
            point = ENV_RATES["PointLTL0-v0"]
            physics = 1 / ENV_RATES.get(env.replace("Vision", ""), point) - 1 / point
            return 1 / (1 / base + physics)
        env = env.replace("Vision", "")
    if f"{env}/genz" in rates:
        return rates[f"{env}/genz"] * _method_factor(key, rates)
    if env in PROFILED_RATES:
        return PROFILED_RATES[env] * _method_factor(key, rates)
    return ENV_RATES.get(env, ENV_RATES["PointLTL0-v0"]) * TRAIN_PER_ENV_STEP * _method_factor(key, rates)


def evaluation_seconds(c: Cell) -> float:
    """Estimated wall time of `c`'s evaluation (`EVAL_S`)."""
    env = _env(c.env_id)
    if env in EVAL_S:
        return EVAL_S[env]
    if "Vision" in env:
        return EVAL_S[VISION_BASE] + EVAL_S.get(env.replace("Vision", ""), EVAL_S_DEFAULT) - EVAL_S["PointLTL0-v0"]
    return EVAL_S_DEFAULT


def seconds(c: Cell, rates: Mapping[str, float] | None = None) -> float:
    """Estimated GPU seconds of `c` from scratch: training, set-up and evaluation."""
    if not c.trains:
        return evaluation_seconds(c)
    return c.seeds * c.total_steps / training_rate(c, rates) + SETUP_S + evaluation_seconds(c)
