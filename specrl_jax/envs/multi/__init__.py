"""Multi-agent Zone worlds: N robots among coloured zones, per-agent propositions `<colour>_<i>`.

Declares `PointLTL0MA3-v0` (the original's: 3 Point agents, zones of radius 0.5) and
`PointLTL0MA2-v0` (two agents, as the paper's tables); `make_multi(config)` builds a custom world
from a `MultiZoneConfig` (N agents, robot, zones, colours, the collision switch).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from specrl_jax.envs.multi.config import MultiZoneConfig, ma_config
from specrl_jax.envs.multi.env import MultiZoneEnv, MultiZoneParams, MultiZoneState
from specrl_jax.envs.multi.wrappers import MultiAutoReset
from specrl_jax.envs.registry import Overrides

#: what `make("PointLTL0MA<n>-v0", **overrides)` accepts (checked by `envs.registry`)
OVERRIDES = Overrides(MultiZoneConfig, MultiZoneParams, fixed=("num_agents", "robot"))


def make_multi(config: MultiZoneConfig, **params: Any) -> tuple[MultiZoneEnv, MultiZoneParams]:
    """Build `(env, params)` from a config; `params` may override `max_steps` (the collision
    switch is the config's `collisions`)."""
    OVERRIDES.check_params(params)
    env = MultiZoneEnv(config)
    return env, dataclasses.replace(env.default_params, **params) if params else env.default_params


def _factory(num_agents: int):
    def build(**overrides: Any) -> tuple[MultiZoneEnv, MultiZoneParams]:
        config_kw, params_kw = OVERRIDES.split(overrides)  # checked by `registry.make`
        return make_multi(ma_config(num_agents, **config_kw), **params_kw)

    return build


def env_ids() -> dict[str, tuple[Any, str]]:
    """The multi-agent Zone registry entries (read by `envs.registry`)."""
    return {
        f"PointLTL0MA{n}-v0": (
            _factory(n), f"{n} Point agents among 8 zones of radius 0.5", OVERRIDES
        )
        for n in (3, 2)
    }


__all__ = [
    "MultiAutoReset", "MultiZoneConfig", "MultiZoneEnv", "MultiZoneParams", "MultiZoneState",
    "make_multi",
]
