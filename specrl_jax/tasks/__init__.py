"""The task layer: the one task loop (a world x a spec source), the spec sources (compiled
automata, reach-avoid sequences, LTL progression, conjunctions of DFAs), and the policy protocol that evaluation and
the baselines share."""

from specrl_jax.tasks.dfa_source import DFASource, DFATask
from specrl_jax.tasks.loop import TaskEnv, TaskState, reward_progress
from specrl_jax.tasks.policy import StatefulPolicy, as_stateful, random_policy, split_action
from specrl_jax.tasks.progression import ProgressionBank, ProgressionSource, ProgressionTask
from specrl_jax.tasks.sources import (
    AutomatonSource,
    AutomatonTask,
    Events,
    SequenceSource,
    SequenceTask,
    SpecBank,
    symbol_sets,
)

__all__ = [
    "AutomatonSource",
    "AutomatonTask",
    "DFASource",
    "DFATask",
    "Events",
    "ProgressionBank",
    "ProgressionSource",
    "ProgressionTask",
    "SequenceSource",
    "SequenceTask",
    "SpecBank",
    "StatefulPolicy",
    "TaskEnv",
    "TaskState",
    "as_stateful",
    "random_policy",
    "reward_progress",
    "split_action",
    "symbol_sets",
]
