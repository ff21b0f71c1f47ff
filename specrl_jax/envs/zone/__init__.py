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
import functools
from typing import TYPE_CHECKING, Any

from specrl_jax import lazy
from specrl_jax.envs.registry import Overrides

if TYPE_CHECKING:
    from specrl_jax.envs.zone.config import ZoneConfig
    from specrl_jax.envs.zone.env import ZoneEnv, ZoneParams

#: names re-exported from the world modules, imported on first use (MJX loads in seconds)
__getattr__ = lazy.exports(__name__, {
    "config": ("COLOR_NAMES", "ZoneConfig", "level_config"),
    "env": ("ZoneEnv", "ZoneParams", "ZoneState"),
    "models": ("Solver",),
})

SUFFIXES = {"": (False, False), ".partial": (True, False), ".overlap": (False, True),
            ".partial_overlap": (True, True)}


@functools.cache
def overrides() -> Overrides:
    """What `make("<robot>LTL<level>...-v0", **overrides)` accepts (checked by
    `envs.registry`): ZoneConfig fields except those the ID sets (robot, camera, LiDAR, level
    keepout, moving zones). Imports the world modules."""
    from specrl_jax.envs.zone.config import ZoneConfig
    from specrl_jax.envs.zone.env import ZoneParams

    return Overrides(
        ZoneConfig, ZoneParams,
        fixed=("robot", "partial", "vision", "overlap", "level", "overlap_alphabet",
               "zone_keepout", "moving_per_color"),
    )


def make_zone(config: ZoneConfig, **params: Any) -> tuple[ZoneEnv, ZoneParams]:
    """Build `(env, params)` from a config; `params` may override `max_steps` (a positive int)."""
    from specrl_jax.envs.zone.env import ZoneEnv

    overrides().check_params(params)
    env = ZoneEnv(config)
    return env, dataclasses.replace(env.default_params, **params) if params else env.default_params


def _factory(robot: str, level: int, partial: bool, overlap: bool, vision: bool = False):
    def build(**options: Any) -> tuple[ZoneEnv, ZoneParams]:
        from specrl_jax.envs.zone.config import level_config

        config_kw, params_kw = overrides().split(options)  # checked by `registry.make`
        config = level_config(robot, level, partial, overlap, vision=vision, **config_kw)
        return make_zone(config, **params_kw)

    return build


def env_ids() -> dict[str, tuple[Any, str, Any]]:
    """The Zone registry entries (read by `envs.registry`; imports no world module)."""
    return {
        f"{robot}LTL{level}{camera}-v0{suffix}": (
            _factory(robot, level, partial, overlap, vision=bool(camera)),
            f"{robot} among 8 zones, level {level}{suffix}{' with camera' if camera else ''}",
            overrides,
        )
        for camera in ("", "Vision")
        for robot in ("Point", "Car", "Ant")
        for level in (0, 1, 2)
        for suffix, (partial, overlap) in SUFFIXES.items()
    }


__all__ = ["COLOR_NAMES", "Solver", "ZoneConfig", "ZoneEnv", "ZoneParams", "ZoneState", "env_ids",
           "level_config", "make_zone", "overrides"]
