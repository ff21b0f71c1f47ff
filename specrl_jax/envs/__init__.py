"""Worlds: grid and physics envs, layouts, sensors and labelling functions.

Importing this package loads only the registry: listing IDs needs no JAX, and each world's
modules load at `make`.
"""

from specrl_jax import lazy
from specrl_jax.envs.registry import list_envs, make, register

#: names re-exported from modules that import JAX, imported on first use
__getattr__ = lazy.exports(__name__, {
    "base": ("Env",),
    "checked": ("checked",),
    "wrappers": ("AutoReset", "BatchedEnv", "EpisodeStatistics", "batch"),
})

__all__ = [
    "AutoReset", "BatchedEnv", "Env", "EpisodeStatistics", "batch", "checked", "list_envs", "make",
    "register",
]
