"""Same-step auto-reset for a multi-agent world, whose termination flags are per agent."""

from __future__ import annotations

from specrl_jax.envs.wrappers import AutoReset


class MultiAutoReset(AutoReset):
    """`envs.wrappers.AutoReset` over a multi-agent world (kept under this name): when the
    world's episode ends (`env.episode_done(terminated, truncated)`: every agent done), the
    returned obs and state are a fresh episode's (a new layout); `info["final_observation"]`
    keeps the last one, `info["final_info"]` that step's info and `info["episode_done"]`
    (bool[]) marks the step. `terminated`/`truncated` (bool[N]) and the labels describe the
    step that was taken."""
