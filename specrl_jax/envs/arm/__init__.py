"""Arm worlds: the 7-DoF Panda reaching coloured spheres on a table, in MuJoCo MJX.

Declares `PandaLTLReach{0,1}Joints-v0` (joint control) and `PandaLTLReach{0,1}-v0` (end-effector
control through the original's IK), each with a `.partial` variant (mode 0 "grippers-only",
mode 1 "grippers+arm"); `make_arm(config)` builds a custom arm world from an `ArmConfig`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, Any

from specrl_jax import lazy
from specrl_jax.envs.arm.config import ArmConfig
from specrl_jax.envs.registry import Overrides

if TYPE_CHECKING:
    from specrl_jax.envs.arm.env import ArmEnv, ArmParams

#: names re-exported from the world module, imported on first use (MJX loads in seconds)
__getattr__ = lazy.exports(__name__, {"env": ("ArmEnv", "ArmParams", "ArmState")})


@functools.cache
def overrides() -> Overrides:
    """What `make("PandaLTLReach...", **overrides)` accepts (checked by `envs.registry`).
    Imports the world module."""
    from specrl_jax.envs.arm.env import ArmParams

    return Overrides(ArmConfig, ArmParams, fixed=("mode", "partial", "control"))


def make_arm(config: ArmConfig, **params: Any) -> tuple[ArmEnv, ArmParams]:
    """Build `(env, params)` from a config; `params` may override `max_steps`."""
    from specrl_jax.envs.arm.env import ArmEnv

    overrides().check_params(params)
    env = ArmEnv(config)
    return env, dataclasses.replace(env.default_params, **params) if params else env.default_params


def _factory(mode: int, partial: bool, control: str):
    def build(**options: Any) -> tuple[ArmEnv, ArmParams]:
        config_kw, params_kw = overrides().split(options)  # checked by `registry.make`
        config = ArmConfig(mode=mode, partial=partial, control=control, **config_kw)
        return make_arm(config, **params_kw)

    return build


def env_ids() -> dict[str, tuple[Any, str, Any]]:
    """The Arm registry entries (read by `envs.registry`; imports no world module)."""
    names = {0: "grippers-only (grasp target in a region)", 1: "grippers+arm (link contact)"}
    controls = {"Joints": ("joints", "joint control"), "": ("ee", "end-effector control")}
    return {
        f"PandaLTLReach{mode}{kind}-v0{suffix}": (
            _factory(mode, suffix == ".partial", control),
            f"Panda arm, {words}, 8 spheres, {names[mode]}{suffix}",
            overrides,
        )
        for kind, (control, words) in controls.items()
        for mode in (0, 1)
        for suffix in ("", ".partial")
    }


__all__ = ["ArmConfig", "ArmEnv", "ArmParams", "ArmState", "env_ids", "make_arm", "overrides"]
