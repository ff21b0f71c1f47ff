"""specrl_jax: a JAX-native, GPU-vectorised SpecRLBench."""

from specrl_jax import cache as _cache
from specrl_jax.envs.registry import list_envs, make

_cache.enable_jax_cache()  # JAX's persistent compilation cache, opt-out: SPECRL_JAX_CACHE_DIR=off

__version__ = "0.1.0"

__all__ = ["__version__", "list_envs", "make"]
