"""Worlds: grid and physics envs, layouts, sensors and labelling functions."""

from specrl_jax.envs.base import Env
from specrl_jax.envs.registry import list_envs, make, register
from specrl_jax.envs.wrappers import AutoReset, BatchedEnv, EpisodeStatistics, batch
from specrl_jax.envs.checked import checked

__all__ = [
    "AutoReset", "BatchedEnv", "Env", "EpisodeStatistics", "batch", "checked", "list_envs", "make",
    "register",
]
