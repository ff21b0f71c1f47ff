"""specrl_jax: a JAX-native, GPU-vectorised SpecRLBench."""

from specrl_jax.envs.registry import list_envs, make

__version__ = "0.1.0"

__all__ = ["__version__", "list_envs", "make"]
