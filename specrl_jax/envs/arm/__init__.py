"""Arm worlds: the 7-DoF Panda reaching coloured spheres on a table, in MuJoCo MJX.

Declares `PandaLTLReach{0,1}Joints-v0` (joint control) and `PandaLTLReach{0,1}-v0` (end-effector
control through the original's IK), each with a `.partial` variant (mode 0 "grippers-only",
mode 1 "grippers+arm"); `make_arm(config)` builds a custom arm world from an `ArmConfig`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from specrl_jax.envs.arm.config import ArmConfig
from specrl_jax.envs.arm.env import ArmEnv, ArmParams, ArmState
from specrl_jax.envs.registry import Overrides

#: what `make("PandaLTLReach...", **overrides)` accepts (checked by `envs.registry`)
OVERRIDES = Overrides(ArmConfig, ArmParams, fixed=("mode", "partial", "control"))


def make_arm(config: ArmConfig, **params: Any) -> tuple[ArmEnv, ArmParams]:
    """Build `(env, params)` from a config; `params` may override `max_steps`."""
    OVERRIDES.check_params(params)
    env = ArmEnv(config)
    return env, dataclasses.replace(env.default_params, **params) if params else env.default_params


def _factory(mode: int, partial: bool, control: str):
    def build(**overrides: Any) -> tuple[ArmEnv, ArmParams]:
        config_kw, params_kw = OVERRIDES.split(overrides)  # checked by `registry.make`
        config = ArmConfig(mode=mode, partial=partial, control=control, **config_kw)
        return make_arm(config, **params_kw)

    return build


def env_ids() -> dict[str, tuple[Any, str]]:
    """The Arm registry entries (read by `envs.registry`)."""
    names = {0: "grippers-only (grasp target in a region)", 1: "grippers+arm (link contact)"}
    controls = {"Joints": ("joints", "joint control"), "": ("ee", "end-effector control")}
    return {
        f"PandaLTLReach{mode}{kind}-v0{suffix}": (
            _factory(mode, suffix == ".partial", control),
            f"Panda arm, {words}, 8 spheres, {names[mode]}{suffix}",
            OVERRIDES,
        )
        for kind, (control, words) in controls.items()
        for mode in (0, 1)
        for suffix in ("", ".partial")
    }


__all__ = ["ArmConfig", "ArmEnv", "ArmParams", "ArmState", "env_ids", "make_arm"]
