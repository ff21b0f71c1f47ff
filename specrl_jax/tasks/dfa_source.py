"""A spec source of conjunctions of DFAs (RAD-Embeddings' tasks) for the task loop.

The task is an index into a `DFABank` (`automata.rad_sampler`) and the state of each conjunct.
Every label advances each conjunct on the label's alphabet symbol. Events: `success` when every
conjunct accepts (the task ends), `violation` when some conjunct can no longer accept (the task
ends; RAD's -1), `progress` when some conjunct changed state without a violation. There are no
Buchi-accepting transitions and no epsilon steps.

`CurriculumDFASource` follows a training curriculum (DeepLTL's) instead: its bank holds each
stage's tasks as one-DFA conjunctions (`curriculum_dfas`: the formulas of
`tasks.curriculum_progression.stage_formulas`, each compiled by our automata into its minimal DFA
of good prefixes), episodes draw from the current stage and the stage advances on the agent's
success (`tasks.curriculum_stages`). Reach-stay tasks (`!K U G p`) are not co-safe, have no DFA
and are left out: a mixed stage keeps its reach-avoid draws (docs/fidelity.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax import automata
from specrl_jax.automata import translate
from specrl_jax.automata.rad_sampler import DFA, DFABank, advance, build_bank, dfa_of_spec, status
from specrl_jax.specs import CurriculumSampler
from specrl_jax.specs.curricula import CurriculumState
from specrl_jax.tasks.curriculum_progression import stage_formulas
from specrl_jax.tasks.curriculum_stages import CurriculumStages, StagedSource
from specrl_jax.tasks.sources import ByContent, Events


class DFABankRef(ByContent):
    """A `DFABank` as static metadata of a task (compares by content, like `SpecBank`)."""

    @property
    def bank(self) -> DFABank:
        return self.tree


@struct.dataclass
class DFATask:
    """An episode's conjunction (index into the bank) and the state of each conjunct."""

    index: jax.Array  # int32[]
    q: jax.Array  # int32[N]
    task_id: jax.Array  # int32[], the curriculum's task id (-1: none or a sampled stage)
    ref: DFABankRef = struct.field(pytree_node=False)

    @property
    def bank(self) -> DFABank:
        return self.ref.bank


class DFASource:
    """A bank of K conjunctions of DFAs; a reset without an index draws one uniformly."""

    may_take_epsilon = False

    def __init__(self, bank: DFABank, alphabet: jax.Array):
        bank_alphabet, env_alphabet = np.asarray(bank.alphabet), np.asarray(alphabet, bool)
        if bank_alphabet.shape != env_alphabet.shape or not np.array_equal(bank_alphabet,
                                                                          env_alphabet):
            raise ValueError(
                f"the DFA bank is over an alphabet of shape {bank_alphabet.shape} that is not "
                f"the world's ({env_alphabet.shape}, same rows in the same order); build the "
                "bank with alphabet=env.alphabet")
        self.bank = bank
        self.ref = DFABankRef(bank)
        self.num_tasks = bank.size
        self.symbol_is_row = True

    @property
    def specs(self) -> DFABank:
        return self.bank

    def init_params(self) -> None:
        return None

    def update_params(self, source_params: Any, stats: dict[str, jax.Array]) -> Any:
        """Source params after a rollout: a uniform draw has none to change."""
        return source_params

    def reset(self, key: jax.Array, source_params: Any = None, index: jax.Array | None = None
              ) -> DFATask:
        if index is None:
            index = jax.random.randint(key, (), 0, self.num_tasks)
        q = jnp.zeros((self.bank.max_conjuncts,), jnp.int32)
        return DFATask(jnp.asarray(index, jnp.int32), q, jnp.int32(-1), self.ref)

    def next_index(self, task: DFATask) -> jax.Array:
        """The conjunction of the next episode after `task`'s: the following one in the bank."""
        return (task.index + 1) % self.num_tasks

    def takes_epsilon(self, task: DFATask, slot: jax.Array) -> jax.Array:
        return jnp.zeros((), bool)

    def step(self, key: jax.Array, task: DFATask, props: jax.Array, symbol: jax.Array | None,
             is_epsilon: jax.Array, slot: jax.Array, source_params: Any = None
             ) -> tuple[DFATask, Events]:
        if symbol is None:
            symbol = automata.label_symbol(self.bank.alphabet, props)
        q_next = advance(self.bank, task.index, task.q, symbol)
        success, violation = status(self.bank, task.index, q_next)
        progress = jnp.any(q_next != task.q) & ~violation
        no = jnp.zeros((), bool)
        return task.replace(q=q_next), Events(progress, no, success, violation)


class CurriculumDFAs(NamedTuple):
    """A curriculum's tasks as a bank of one-DFA conjunctions, stage after stage, and the formula
    of each row by stage (`len(formulas[s])` rows in stage s)."""

    bank: DFABank
    formulas: list[list[str]]

    @property
    def stage_sizes(self) -> list[int]:
        return [len(stage) for stage in self.formulas]


def curriculum_dfas(sampler: CurriculumSampler, propositions: Sequence[str],
                    alphabet: np.ndarray, per_stage: int, seed: int = 0) -> CurriculumDFAs:
    """The tasks of `stage_formulas(sampler, propositions, per_stage, seed)` as minimal DFAs of
    good prefixes over `alphabet` bool[A, P] (`automata.translate`, then
    `rad_sampler.dfa_of_spec`), reach-stay formulas (not co-safe) left out.

    Raises:
        ValueError: a stage is left without tasks.
    """
    alphabet = np.asarray(alphabet, bool)
    dfas: dict[str, DFA | None] = {}  # sampled stages repeat formulas: translate each once
    kept: list[list[str]] = []
    for stage, formulas in enumerate(stage_formulas(sampler, propositions, per_stage, seed)):
        for formula in formulas:
            if formula not in dfas:
                automaton = translate.translate(formula, propositions, alphabet)
                dfas[formula] = dfa_of_spec(automaton)[0] if automaton.is_finite else None
        kept.append([f for f in formulas if dfas[f] is not None])
        if not kept[-1]:
            raise ValueError(f"stage {stage} of {sampler.curriculum.name} has no co-safe task")
    bank = build_bank([[dfas[f]] for stage in kept for f in stage], alphabet, max_conjuncts=1)
    return CurriculumDFAs(bank, kept)


class CurriculumDFASource(StagedSource, DFASource):
    """`DFASource` whose episodes follow a curriculum: source params are the `CurriculumState`;
    the bank's rows are the stages' tasks, `stage_sizes` rows per stage (`curriculum_dfas`).

    A finished episode's `task_id` is its slot in an enumerated stage, -1 in a sampled one;
    `update_params` advances the stage on the episodes' success.
    """

    def __init__(self, bank: DFABank, alphabet: jax.Array, sampler: CurriculumSampler,
                 stage_sizes: Sequence[int]):
        super().__init__(bank, alphabet)
        # a conjunction can succeed where each conjunct can (one conjunct per task here)
        can_succeed = np.asarray(bank.live)[:, :, 0].all(axis=1)
        self.stages = CurriculumStages(sampler, stage_sizes, can_succeed)

    def reset(self, key: jax.Array, source_params: CurriculumState | None = None,
              index: jax.Array | None = None) -> DFATask:
        if index is not None:
            return super().reset(key, None, index)
        state = self.init_params() if source_params is None else source_params
        row, task_id = self.stages.draw(key, state)
        return super().reset(key, None, row).replace(task_id=task_id)

    def next_index(self, task: DFATask) -> None:
        """None: every episode draws from the current stage."""
        return None
