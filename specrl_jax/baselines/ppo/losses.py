"""Advantage estimation and the two PPO losses: clipped PPO (torch-ac conventions) and GenZ-LTL's
RCO (PPO-Lagrangian with a Hamilton-Jacobi reachability cost).

Time-major arrays are `[T, B]`: T rollout steps, B envs. `done[t]` marks that step t ended a
segment, so nothing is bootstrapped from step t + 1 (episode end, time-out when time-outs are
terminal, or GenZ's subgoal switch).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from specrl_jax.baselines.ppo.networks import PolicyOutput


class Batch(NamedTuple):
    """One (mini)batch of samples, leading axis N; `obs` is any pytree with leading axis N."""

    obs: object
    action: jax.Array  # int32[N] or float32[N, D]
    log_prob: jax.Array  # float32[N], behaviour policy
    value: jax.Array  # float32[N], V before the update
    cost_value: jax.Array  # float32[N], V_c before the update
    advantage: jax.Array  # float32[N]
    target: jax.Array  # float32[N], return target R = V_old + A
    cost_advantage: jax.Array  # float32[N]
    cost_target: jax.Array  # float32[N]


class LossConfig(NamedTuple):
    clip_eps: float = 0.2
    vf_coef: float = 0.5
    ent_coef: float = 0.01
    clip_value: bool = True
    normalize_advantages: bool = False
    gamma: float = 0.94
    target_cost: float = -0.05
    multiplier_min: float = 0.01
    multiplier_max: float = 5.0
    entropy_per_action_dim: bool = True


def _entropy(out: PolicyOutput, cfg: LossConfig) -> jax.Array:
    """The mean entropy the bonus rewards: per action dimension (a Gaussian's summed entropy
    over its `D` dimensions, divided by `D`), as torch-ac's `dist.entropy().mean()` averages a
    `Normal`'s per-dimension entropies, or the joint entropy (SB3) when not
    `entropy_per_action_dim`."""
    entropy = jnp.mean(out.pi.entropy())
    return entropy / out.pi.action_dims if cfg.entropy_per_action_dim else entropy


def compute_gae(
    reward: jax.Array, value: jax.Array, done: jax.Array, last_value: jax.Array, gamma: float, lam: float
) -> tuple[jax.Array, jax.Array]:
    """GAE(gamma, lam). reward/value/done `[T, B]`, last_value `[B]` (V of the state after step T-1).

    Returns `(advantage, target)`, both float32[T, B], with `target = advantage + value`.
    """
    next_value = jnp.concatenate([value[1:], last_value[None]], axis=0)
    mask = 1.0 - done.astype(jnp.float32)
    delta = reward + gamma * next_value * mask - value

    def backward(carry: jax.Array, xs: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        delta_t, mask_t = xs
        carry = delta_t + gamma * lam * mask_t * carry
        return carry, carry

    _, advantage = jax.lax.scan(backward, jnp.zeros_like(last_value), (delta, mask), reverse=True)
    return advantage, advantage + value


def compute_reachability_cost(
    cost: jax.Array, cost_value: jax.Array, done: jax.Array, last_cost_value: jax.Array, gamma: float, lam: float
) -> tuple[jax.Array, jax.Array]:
    """GenZ-LTL's HJ-reachability cost estimates, `[T, B]` in and out.

    `delta_c = (1 - gamma) c + gamma max(c, V_c') mask - V_c`, advantage = GAE(gamma, lam) of delta_c;
    target `C_t = max(c_t, C_{t+1} mask_t)` with `C_T = 0` (the realised worst future cost, not
    bootstrapped). Returns `(cost_advantage, cost_target)`.
    """
    next_cost_value = jnp.concatenate([cost_value[1:], last_cost_value[None]], axis=0)
    mask = 1.0 - done.astype(jnp.float32)
    delta = (1 - gamma) * cost + gamma * jnp.maximum(cost, next_cost_value) * mask - cost_value

    def backward(carry, xs):
        adv, worst = carry
        delta_t, cost_t, mask_t = xs
        adv = delta_t + gamma * lam * mask_t * adv
        worst = jnp.maximum(cost_t, worst * mask_t)
        return (adv, worst), (adv, worst)

    zeros = jnp.zeros_like(last_cost_value)
    _, (advantage, target) = jax.lax.scan(backward, (zeros, zeros), (delta, cost, mask), reverse=True)
    return advantage, target


def _value_loss(value: jax.Array, old: jax.Array, target: jax.Array, cfg: LossConfig) -> jax.Array:
    loss = jnp.square(value - target)
    if cfg.clip_value:
        clipped = old + jnp.clip(value - old, -cfg.clip_eps, cfg.clip_eps)
        loss = jnp.maximum(loss, jnp.square(clipped - target))
    return jnp.mean(loss)


def _advantage(batch: Batch, cfg: LossConfig) -> jax.Array:
    adv = batch.advantage
    if cfg.normalize_advantages:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    return adv


def ppo_loss(out: PolicyOutput, batch: Batch, cfg: LossConfig) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Clipped PPO: `-mean(min(rA, clip(r)A)) - c_ent H + c_v L_V`; returns `(loss, metrics)`."""
    log_prob = out.pi.log_prob(batch.action)
    ratio = jnp.exp(log_prob - batch.log_prob)
    adv = _advantage(batch, cfg)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - cfg.clip_eps, 1 + cfg.clip_eps) * adv)
    policy_loss = -jnp.mean(surrogate)
    entropy = _entropy(out, cfg)
    value_loss = _value_loss(out.value, batch.value, batch.target, cfg)
    loss = policy_loss - cfg.ent_coef * entropy + cfg.vf_coef * value_loss
    approx_kl = jnp.mean(batch.log_prob - log_prob)
    return loss, {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": entropy, "approx_kl": approx_kl}


def rco_loss(out: PolicyOutput, batch: Batch, cfg: LossConfig) -> tuple[jax.Array, dict[str, jax.Array]]:
    """GenZ-LTL's RCO loss: PPO plus a state-dependent Lagrangian term on the reachability cost.

    `lam = clip(multiplier, lo, hi)`, `g = r A_c + (1 - gamma) C - target_cost`;
    policy `mean(-min(rA, clip(r)A) + sg(lam) g)`, multiplier `-mean(lam sg(g))`,
    total `policy + c_v (L_V + L_Vc + L_lam) - c_ent H`.
    """
    log_prob = out.pi.log_prob(batch.action)
    ratio = jnp.exp(log_prob - batch.log_prob)
    adv = _advantage(batch, cfg)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - cfg.clip_eps, 1 + cfg.clip_eps) * adv)
    lam = jnp.clip(out.multiplier, cfg.multiplier_min, cfg.multiplier_max)
    constraint = ratio * batch.cost_advantage + (1 - cfg.gamma) * batch.cost_target - cfg.target_cost
    policy_loss = jnp.mean(-surrogate + jax.lax.stop_gradient(lam) * constraint)
    multiplier_loss = -jnp.mean(lam * jax.lax.stop_gradient(constraint))
    entropy = _entropy(out, cfg)
    value_loss = _value_loss(out.value, batch.value, batch.target, cfg)
    cost_value_loss = _value_loss(out.cost_value, batch.cost_value, batch.cost_target, cfg)
    loss = (
        policy_loss
        + cfg.vf_coef * (value_loss + cost_value_loss + multiplier_loss)
        - cfg.ent_coef * entropy
    )
    approx_kl = jnp.mean(batch.log_prob - log_prob)
    metrics = {
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "cost_value_loss": cost_value_loss,
        "multiplier_loss": multiplier_loss,
        "multiplier": jnp.mean(lam),
        "entropy": entropy,
        "approx_kl": approx_kl,
    }
    return loss, metrics


LOSSES = {"ppo": ppo_loss, "rco": rco_loss}
