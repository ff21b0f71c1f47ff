"""Train a method on a tiny world and read its learning curve (shared by the learning tests)."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from specrl_jax.baselines.ppo import make_train
from xla_options import OPTIMISED


def train_rows(module: Any, method: Any, cfg: Any, updates: int, optimised: bool = True
               ) -> tuple[Any, list[dict]]:
    """The trained runner state and one summarised metrics row per update (`module.summarise`),
    compiled at XLA's default optimisation level (hundreds of updates), or with `optimised`
    False at the suite's level 0 (where compiling costs more time than running gains)."""
    runner, metrics = jax.jit(make_train(cfg, method),
                              compiler_options=OPTIMISED if optimised else None)(jax.random.key(1))
    rows = [module.summarise({k: float(v[i]) for k, v in metrics.items()}) for i in range(updates)]
    return runner, rows


def early_late(rows: list[dict], name: str = "success_rate", window: int = 5
               ) -> tuple[float, float]:
    """Mean of `name` over the first and the last `window` updates."""
    return (float(np.mean([r[name] for r in rows[:window]])),
            float(np.mean([r[name] for r in rows[-window:]])))
