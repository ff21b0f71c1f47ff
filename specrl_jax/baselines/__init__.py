"""Specification-guided RL baselines on one shared PPO trainer (`specrl_jax.baselines.ppo`)."""
