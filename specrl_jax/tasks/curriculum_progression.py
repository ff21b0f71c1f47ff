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


#: `task_id` of a formula that can never progress to true (reach-stay `!K U G p`): its episodes
#: end by violation or time-out only, so the stage's success leaves them out
NEVER_TRUE = -2


def can_become_true(bank: ProgressionBank) -> np.ndarray:
    """bool[K]: some word progresses formula k to true (host fixpoint over the bank's table)."""
    delta = np.asarray(bank.delta)
    good = np.asarray(bank.is_true).copy()
    while True:
        grown = good | good[delta].any(axis=1)
        if (grown == good).all():
            return good[np.asarray(bank.roots)]
        good = grown


class CurriculumProgressionSource:
    """`ProgressionSource` whose episodes follow a curriculum: source params are the
    `CurriculumState`; formulas of stage s are the bank's rows `start[s] .. start[s] + size[s]`.

    Events as `ProgressionSource`; a finished episode's `task_id` is its slot in an enumerated
    stage, -1 in a sampled one, `NEVER_TRUE` for a formula that cannot succeed; `update_params`
    advances the stage from the others' success.
    """

    def __init__(self, bank: ProgressionBank, alphabet: jax.Array, sampler: CurriculumSampler,
                 stage_sizes: Sequence[int]):
        stages = sampler.curriculum.stages
        if len(stage_sizes) != len(stages) or min(stage_sizes) < 1:
            raise ValueError(f"need one positive size per stage of {sampler.curriculum.name} "
                             f"({len(stages)}), got {tuple(stage_sizes)}")
        if sum(stage_sizes) != bank.num_formulas:
            raise ValueError(f"the stages hold {sum(stage_sizes)} formulas, the bank "
                             f"{bank.num_formulas}")
        for size, tasks in zip(stage_sizes, sampler.tasks):
            if tasks is not None and size != tasks.reach.shape[0]:
                raise ValueError(f"an enumerated stage needs all {tasks.reach.shape[0]} tasks, "
                                 f"got {size}")
        self.base = ProgressionSource(bank, alphabet)
        self.bank = bank
        self.sampler = sampler
        self.num_tasks = bank.num_formulas
        self.may_take_epsilon = False
        self.symbol_is_row = self.base.symbol_is_row
        self.max_size = max(stage_sizes)
        self.start = jnp.asarray(np.cumsum([0, *stage_sizes[:-1]]), jnp.int32)
        self.size = jnp.asarray(stage_sizes, jnp.int32)
        self.enumerated = jnp.asarray([s.is_enumerated for s in stages])
        self.can_succeed = jnp.asarray(can_become_true(bank))
        # uniform where no temperature (sampled stages, or an enumerated stage without one)
        self.inverse_temperature = jnp.asarray(
            [0.0 if s.temperature is None else 1.0 / s.temperature for s in stages], jnp.float32)

    @property
    def specs(self) -> ProgressionBank:
        return self.bank

    def init_params(self) -> CurriculumState:
        return self.sampler.init()

    def update_params(self, state: CurriculumState, stats: dict[str, jax.Array]
                      ) -> CurriculumState:
        """The curriculum's stage advance from a rollout's stats `[T, B]` (`_task_id`,
        `_finished`, `_success`), episodes of formulas that cannot succeed left out."""
        task_id = stats["_task_id"].reshape(-1)
        finished = stats["_finished"].reshape(-1) & (task_id != NEVER_TRUE)
        return self.sampler.update(state, task_id, finished, stats["_success"].reshape(-1))

    def reset(self, key: jax.Array, source_params: CurriculumState | None = None,
              index: jax.Array | None = None) -> ProgressionTask:
        if index is not None:
            return self.base.reset(key, None, index)
        state = self.init_params() if source_params is None else source_params
        stage = state.stage
        slots = jnp.arange(self.max_size)
        success = jnp.zeros(self.max_size).at[: state.task_success.shape[0]].set(
            state.task_success[: self.max_size])
        logits = jnp.where(slots < self.size[stage],
                           -success * self.inverse_temperature[stage], -jnp.inf)
        slot = jax.random.categorical(key, logits).astype(jnp.int32)
        formula = self.start[stage] + slot
        task = self.base.reset(key, None, formula)
        sampled_id = jnp.where(self.can_succeed[formula], -1, NEVER_TRUE)
        return task.replace(
            task_id=jnp.where(self.enumerated[stage], slot, sampled_id).astype(jnp.int32))

    def next_index(self, task: ProgressionTask) -> None:
        return None

    def takes_epsilon(self, task: ProgressionTask, slot: jax.Array) -> jax.Array:
        return jnp.zeros((), bool)

    def step(self, key: jax.Array, task: ProgressionTask, props: jax.Array,
             symbol: jax.Array | None, is_epsilon: jax.Array, slot: jax.Array,
             source_params: Any = None) -> tuple[ProgressionTask, Events]:
        return self.base.step(key, task, props, symbol, is_epsilon, slot)
