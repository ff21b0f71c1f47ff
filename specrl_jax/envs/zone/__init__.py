"""Zone worlds: Point, Car and Ant robots among coloured zones, in MuJoCo MJX.

Declares `{Point,Car,Ant}LTL{0,1,2}[Vision]-v0` with the suffixes `.partial`, `.overlap` and
`.partial_overlap` (the `Vision` IDs add the robot camera's frame, `obs["image"]`; their
`image_size` is 256 x 256 unless overridden); `make_zone(config)` builds a custom world from a
`ZoneConfig` (`vision=True` for a camera). Options: the
physics backend (`physics="auto"` default: MuJoCo Warp for Car and Ant on one CUDA GPU with
warp-lang, MJX's JAX implementation otherwise; or `"jax"` / `"warp"` by name) and opt-in
layout-bank resets (`env.with_map_bank(key, params, num_maps)`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from specrl_jax.envs.zone.config import COLOR_NAMES, ZoneConfig, level_config
from specrl_jax.envs.zone.env import ZoneEnv, ZoneParams, ZoneState
from specrl_jax.envs.zone.models import Solver

SUFFIXES = {"": (False, False), ".partial": (True, False), ".overlap": (False, True),
            ".partial_overlap": (True, True)}


def _check_params(params: dict[str, Any], config_fields: tuple[str, ...] = ()) -> None:
    """Reject unknown or bad ZoneParams overrides before any world is built."""
    unknown = sorted(set(params) - {"max_steps"})
    if unknown:
        where = " (nor ZoneConfig fields)" if config_fields else ""
        accepted = f"ZoneConfig fields {sorted(config_fields)} and " if config_fields else ""
        raise ValueError(
            f"unknown ZoneParams fields {unknown}{where}; accepted: {accepted}ZoneParams fields "
            "['max_steps']"
        )
    max_steps = params.get("max_steps", 1)
    if not isinstance(max_steps, int) or isinstance(max_steps, bool) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive int, got {max_steps!r}")


def make_zone(config: ZoneConfig, **params: Any) -> tuple[ZoneEnv, ZoneParams]:
    """Build `(env, params)` from a config; `params` may override `max_steps` (a positive int)."""
    _check_params(params)
    env = ZoneEnv(config)
    return env, dataclasses.replace(env.default_params, **params) if params else env.default_params


def _factory(robot: str, level: int, partial: bool, overlap: bool, vision: bool = False):
    config_fields = {f.name for f in dataclasses.fields(ZoneConfig) if f.init}

    def build(**overrides: Any) -> tuple[ZoneEnv, ZoneParams]:
        fixed = sorted(set(overrides) & {"robot", "partial", "overlap", "level", "vision"})
        if fixed:
            raise ValueError(
                f"{fixed} are fixed by the env ID ({robot}, level {level}); pick another ID, or "
                "build a custom world with make_zone(ZoneConfig(...))"
            )
        config_kw = {k: v for k, v in overrides.items() if k in config_fields}
        params_kw = {k: v for k, v in overrides.items() if k not in config_fields}
        _check_params(params_kw, tuple(config_fields - {"robot", "partial", "vision"}))
        config = level_config(robot, level, partial, overlap, vision=vision, **config_kw)
        return make_zone(config, **params_kw)

    return build


def env_ids() -> dict[str, tuple[Any, str]]:
    """The Zone registry entries (read by `envs.registry`)."""
    return {
        f"{robot}LTL{level}{camera}-v0{suffix}": (
            _factory(robot, level, partial, overlap, vision=bool(camera)),
            f"{robot} among 8 zones, level {level}{suffix}{' with camera' if camera else ''}",
        )
        for camera in ("", "Vision")
        for robot in ("Point", "Car", "Ant")
        for level in (0, 1, 2)
        for suffix, (partial, overlap) in SUFFIXES.items()
    }


__all__ = ["COLOR_NAMES", "Solver", "ZoneConfig", "ZoneEnv", "ZoneParams", "ZoneState", "make_zone"]
