"""A training curriculum (DeepLTL's) over one bank of tasks: each stage a slice of the bank.

Shared by the sources whose tasks are bank rows (LTL2Action's formulas,
`tasks.curriculum_progression`; RAD-Embeddings' DFAs, `tasks.dfa_source`). Stage s holds rows
`start[s] .. start[s] + size[s]`: an enumerated stage all of the curriculum's tasks in its order
(a row's slot is the curriculum's task index), a sampled stage any number of its draws. An
episode draws a row of the current stage as the curriculum draws a task (softmax(-success /
temperature) over an enumerated stage, uniform over a sampled stage's rows), and the stage
advances by `CurriculumSampler.update` on the episodes' success, as DeepLTL's does; episodes of
rows that can never succeed (reach-stay formulas) are left out of the stage's success.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.specs import CurriculumSampler
from specrl_jax.specs.curricula import CurriculumState

#: `task_id` of a row that can never succeed (e.g. reach-stay `!K U G p`): its episodes end by
#: violation or time-out only, so the stage's success leaves them out
NEVER_TRUE = -2


class CurriculumStages:
    """The stages of `sampler`'s curriculum as consecutive slices of a bank of K rows, of
    `stage_sizes` rows each; `can_succeed` bool[K] marks the rows some episode can complete."""

    def __init__(self, sampler: CurriculumSampler, stage_sizes: Sequence[int],
                 can_succeed: np.ndarray):
        stages = sampler.curriculum.stages
        if len(stage_sizes) != len(stages) or min(stage_sizes) < 1:
            raise ValueError(f"need one positive size per stage of {sampler.curriculum.name} "
                             f"({len(stages)}), got {tuple(stage_sizes)}")
        if sum(stage_sizes) != len(can_succeed):
            raise ValueError(f"the stages hold {sum(stage_sizes)} tasks, the bank "
                             f"{len(can_succeed)}")
        for size, tasks in zip(stage_sizes, sampler.tasks):
            if tasks is not None and size != tasks.reach.shape[0]:
                raise ValueError(f"an enumerated stage needs all {tasks.reach.shape[0]} tasks, "
                                 f"got {size}")
        self.sampler = sampler
        self.max_size = max(stage_sizes)
        self.start = jnp.asarray(np.cumsum([0, *stage_sizes[:-1]]), jnp.int32)
        self.size = jnp.asarray(stage_sizes, jnp.int32)
        self.enumerated = jnp.asarray([s.is_enumerated for s in stages])
        self.can_succeed = jnp.asarray(can_succeed, bool)
        # uniform where no temperature (sampled stages, or an enumerated stage without one)
        self.inverse_temperature = jnp.asarray(
            [0.0 if s.temperature is None else 1.0 / s.temperature for s in stages], jnp.float32)

    def init_params(self) -> CurriculumState:
        return self.sampler.init()

    def update_params(self, state: CurriculumState, stats: dict[str, jax.Array]
                      ) -> CurriculumState:
        """The curriculum's stage advance from a rollout's stats `[T, B]` (`_task_id`,
        `_finished`, `_success`), episodes of rows that cannot succeed left out."""
        task_id = stats["_task_id"].reshape(-1)
        finished = stats["_finished"].reshape(-1) & (task_id != NEVER_TRUE)
        return self.sampler.update(state, task_id, finished, stats["_success"].reshape(-1))

    def draw(self, key: jax.Array, state: CurriculumState) -> tuple[jax.Array, jax.Array]:
        """(row, task_id) int32[]: a bank row of the current stage, and the episode's task id
        (its slot in an enumerated stage, -1 in a sampled one, `NEVER_TRUE` where the row
        cannot succeed)."""
        stage = state.stage
        slots = jnp.arange(self.max_size)
        success = jnp.zeros(self.max_size).at[: state.task_success.shape[0]].set(
            state.task_success[: self.max_size])
        logits = jnp.where(slots < self.size[stage],
                           -success * self.inverse_temperature[stage], -jnp.inf)
        slot = jax.random.categorical(key, logits).astype(jnp.int32)
        row = self.start[stage] + slot
        sampled_id = jnp.where(self.can_succeed[row], -1, NEVER_TRUE)
        return row, jnp.where(self.enumerated[stage], slot, sampled_id).astype(jnp.int32)


class StagedSource:
    """Source params and their update for a task source that follows `self.stages`
    (`CurriculumStages`): the curriculum state, advanced on the episodes' success."""

    stages: CurriculumStages

    def init_params(self) -> CurriculumState:
        return self.stages.init_params()

    def update_params(self, state: CurriculumState, stats: dict[str, jax.Array]
                      ) -> CurriculumState:
        """The curriculum's stage advance (`CurriculumStages.update_params`)."""
        return self.stages.update_params(state, stats)
