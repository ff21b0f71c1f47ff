"""Multi-agent Zone worlds: N robots among coloured zones, per-agent propositions `<colour>_<i>`.

Declares `PointLTL0MA3-v0` (the original's: 3 Point agents, zones of radius 0.5) and
`PointLTL0MA2-v0` (two agents, as the paper's tables); `make_multi(config)` builds a custom world
from a `MultiZoneConfig` (N agents, robot, zones, colours, the collision switch).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, Any

from specrl_jax import lazy
from specrl_jax.envs.registry import Overrides

if TYPE_CHECKING:
    from specrl_jax.envs.multi.config import MultiZoneConfig
    from specrl_jax.envs.multi.env import MultiZoneEnv, MultiZoneParams

#: names re-exported from the world modules, imported on first use (MJX loads in seconds)
__getattr__ = lazy.exports(__name__, {
    "config": ("MultiZoneConfig", "ma_config"),
    "env": ("MultiZoneEnv", "MultiZoneParams", "MultiZoneState"),
    "wrappers": ("MultiAutoReset",),
})


@functools.cache
def overrides() -> Overrides:
    """What `make("PointLTL0MA<n>-v0", **overrides)` accepts (checked by `envs.registry`).
    Imports the world modules."""
    from specrl_jax.envs.multi.config import MultiZoneConfig
    from specrl_jax.envs.multi.env import MultiZoneParams

    return Overrides(MultiZoneConfig, MultiZoneParams, fixed=("num_agents", "robot"))


def make_multi(config: MultiZoneConfig, **params: Any) -> tuple[MultiZoneEnv, MultiZoneParams]:
    """Build `(env, params)` from a config; `params` may override `max_steps` (the collision
    switch is the config's `collisions`)."""
    from specrl_jax.envs.multi.env import MultiZoneEnv

    overrides().check_params(params)
    env = MultiZoneEnv(config)
    return env, dataclasses.replace(env.default_params, **params) if params else env.default_params


def _factory(num_agents: int):
    def build(**options: Any) -> tuple[MultiZoneEnv, MultiZoneParams]:
        from specrl_jax.envs.multi.config import ma_config

        config_kw, params_kw = overrides().split(options)  # checked by `registry.make`
        return make_multi(ma_config(num_agents, **config_kw), **params_kw)

    return build


def env_ids() -> dict[str, tuple[Any, str, Any]]:
    """The multi-agent Zone registry entries (read by `envs.registry`; imports no world
    module)."""
    return {
        f"PointLTL0MA{n}-v0": (
            _factory(n), f"{n} Point agents among 8 zones of radius 0.5", overrides
        )
        for n in (3, 2)
    }


__all__ = [
    "MultiAutoReset", "MultiZoneConfig", "MultiZoneEnv", "MultiZoneParams", "MultiZoneState",
    "env_ids", "ma_config", "make_multi", "overrides",
]
