"""A spec source of conjunctions of DFAs (RAD-Embeddings' tasks) for the task loop.

The task is an index into a `DFABank` (`automata.rad_sampler`) and the state of each conjunct.
Every label advances each conjunct on the label's alphabet symbol. Events: `success` when every
conjunct accepts (the task ends), `violation` when some conjunct can no longer accept (the task
ends; RAD's -1), `progress` when some conjunct changed state without a violation. There are no
Buchi-accepting transitions and no epsilon steps.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax import automata
from specrl_jax.automata.rad_sampler import DFABank, advance, status
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

    def reset(self, key: jax.Array, source_params: Any = None, index: jax.Array | None = None
              ) -> DFATask:
        if index is None:
            index = jax.random.randint(key, (), 0, self.num_tasks)
        q = jnp.zeros((self.bank.max_conjuncts,), jnp.int32)
        return DFATask(jnp.asarray(index, jnp.int32), q, self.ref)

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
