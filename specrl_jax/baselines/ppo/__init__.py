"""The shared PPO trainer: `make_train(config, method) -> train(key)`."""

from specrl_jax.baselines.ppo.train import (
    Method,
    PPOConfig,
    RunnerState,
    Trainer,
    env_mesh,
    make_train,
)

__all__ = ["Method", "PPOConfig", "RunnerState", "Trainer", "env_mesh", "make_train"]
