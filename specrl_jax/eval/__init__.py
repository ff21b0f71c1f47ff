"""Compiled mass evaluation, the paper's metrics, reference policies, tables and plots."""

from specrl_jax.eval.evaluate import EvalResult, evaluate, make_evaluator, record_episodes
from specrl_jax.eval.metrics import EpisodeTable, per_seed_metrics, summarize
from specrl_jax.eval.planner import oracle_policy
from specrl_jax.tasks.policy import StatefulPolicy, as_stateful, random_policy

__all__ = [
    "EpisodeTable",
    "EvalResult",
    "StatefulPolicy",
    "as_stateful",
    "evaluate",
    "make_evaluator",
    "oracle_policy",
    "per_seed_metrics",
    "random_policy",
    "record_episodes",
    "summarize",
]
