"""A training curriculum (DeepLTL's) as LTL formulas for progression-conditioned methods.

Each stage of a `specs.Curriculum` becomes a slice of one progression bank: an enumerated stage
holds all of its tasks (in enumeration order, so a formula's slot is the curriculum's task
index), a sampled stage `per_stage` draws of its mixture. A reach-avoid sequence
[(R1, A1), (R2, A2), ...] is the formula `!(A1) U (R1 & (!(A2) U (R2 & ...)))`, `F(R & ...)` where
an avoid set is empty; a reach-stay task (epsilon, avoid K; stay in p) is `!K U G p`
(`specs.formulas.sequence_to_formula`). Episodes draw a formula of the current stage as the
curriculum draws a task (softmax(-success / temperature) over an enumerated stage, uniform over
a sampled stage's draws), and the stage advances by `CurriculumSampler.update` on the episodes'
success, as DeepLTL's does; a reach-stay formula never progresses to true, so its episodes are
left out of the stage's success (else ZoneEnv's stage 4, 60 % reach-stay, could never pass 0.9). Under the "at most one proposition" alphabets the formula of a
sequence is violated only where the sequence is, and completed where the sequence is unless the
sequence was violated first: the formula does not commit to the first visit of R_i
(docs/fidelity.md, "LTL2Action: training formulas").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.specs import CurriculumSampler
from specrl_jax.specs.curricula import CurriculumState
from specrl_jax.specs.formulas import sequence_to_formula
from specrl_jax.tasks.curriculum_stages import NEVER_TRUE as NEVER_TRUE  # this module's task id
from specrl_jax.tasks.curriculum_stages import CurriculumStages, StagedSource
from specrl_jax.tasks.progression import ProgressionBank, ProgressionSource, ProgressionTask
from specrl_jax.tasks.sources import Events


def _formulas(batch: Any, propositions: Sequence[str]) -> list[str]:
    """A batch of sequences (leading axis K, host arrays) as K formula texts."""
    batch = jax.device_get(batch)
    num = int(np.asarray(batch.length).shape[0])
    return [sequence_to_formula(jax.tree.map(lambda x, i=i: np.asarray(x)[i], batch), propositions)
            for i in range(num)]


def stage_formulas(sampler: CurriculumSampler, propositions: Sequence[str], per_stage: int,
                   seed: int = 0) -> list[list[str]]:
    """The curriculum's tasks as formula texts, one list per stage: every task of an
    enumerated stage in the curriculum's order, `per_stage` draws (`sample_formulas` with seed
    `seed + stage`) of a sampled stage."""
    if per_stage < 1:
        raise ValueError(f"per_stage must be >= 1, got {per_stage}")
    if len(propositions) < 3:
        # with 2, a reach set of both leaves the next pair nothing to reach
        raise ValueError(f"the curricula need at least 3 propositions, got {tuple(propositions)}")
    out = []
    for index, tasks in enumerate(sampler.tasks):
        if tasks is None:
            out.append(sampler.sample_formulas(seed + index, index, per_stage, propositions))
        else:
            out.append(_formulas(tasks, propositions))
    return out


def can_become_true(bank: ProgressionBank) -> np.ndarray:
    """bool[K]: some word progresses formula k to true (host fixpoint over the bank's table)."""
    delta = np.asarray(bank.delta)
    good = np.asarray(bank.is_true).copy()
    while True:
        grown = good | good[delta].any(axis=1)
        if (grown == good).all():
            return good[np.asarray(bank.roots)]
        good = grown


class CurriculumProgressionSource(StagedSource):
    """`ProgressionSource` whose episodes follow a curriculum: source params are the
    `CurriculumState`; the bank's rows are the stages' formulas, stage after stage
    (`tasks.curriculum_stages`).

    Events as `ProgressionSource`; a finished episode's `task_id` is its slot in an enumerated
    stage, -1 in a sampled one, `NEVER_TRUE` for a formula that cannot succeed; `update_params`
    advances the stage from the others' success.
    """

    def __init__(self, bank: ProgressionBank, alphabet: jax.Array, sampler: CurriculumSampler,
                 stage_sizes: Sequence[int]):
        self.stages = CurriculumStages(sampler, stage_sizes, can_become_true(bank))
        self.base = ProgressionSource(bank, alphabet)
        self.bank = bank
        self.sampler = sampler
        self.num_tasks = bank.num_formulas
        self.may_take_epsilon = False
        self.symbol_is_row = self.base.symbol_is_row
        self.can_succeed = self.stages.can_succeed

    @property
    def specs(self) -> ProgressionBank:
        return self.bank

    def reset(self, key: jax.Array, source_params: CurriculumState | None = None,
              index: jax.Array | None = None) -> ProgressionTask:
        if index is not None:
            return self.base.reset(key, None, index)
        state = self.init_params() if source_params is None else source_params
        formula, task_id = self.stages.draw(key, state)
        return self.base.reset(key, None, formula).replace(task_id=task_id)

    def next_index(self, task: ProgressionTask) -> None:
        return None

    def takes_epsilon(self, task: ProgressionTask, slot: jax.Array) -> jax.Array:
        return jnp.zeros((), bool)

    def step(self, key: jax.Array, task: ProgressionTask, props: jax.Array,
             symbol: jax.Array | None, is_epsilon: jax.Array, slot: jax.Array,
             source_params: Any = None) -> tuple[ProgressionTask, Events]:
        return self.base.step(key, task, props, symbol, is_epsilon, slot)
