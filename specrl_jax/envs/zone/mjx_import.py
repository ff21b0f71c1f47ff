"""`mujoco.mjx`, imported without the notice it prints when the optional Warp backend is absent.

Without warp-lang specrl_jax uses MJX's JAX implementation only; the notice ("Failed to import
warp") would otherwise appear on every `import specrl_jax`.
"""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

__all__ = ["mjx"]
