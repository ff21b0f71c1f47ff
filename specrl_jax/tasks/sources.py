"""Spec sources: where the task loop gets each episode's task, and how a task follows the labels.

A source is a static Python object with pure functions over a small task pytree:

    task = source.reset(key, source_params, index)         # a fresh task (index: see below)
    is_eps = source.takes_epsilon(task, slot)              # bool[], an epsilon step is taken
    task, events = source.step(key, task, props, symbol, is_eps, source_params)

`source_params` is the trainer-carried task distribution (a curriculum state) or None.

- `AutomatonSource`: a stacked bank of compiled specs (evaluation, formula-conditioned training);
  the task is the spec index and the automaton state; `index` picks the spec. An epsilon jump
  that turns out wrong (the run it began dies while the formula is still open, e.g. leaving `x`
  after jumping into the loop of `F G x`) falls back to the run that never jumped
  (`fall_back_run`).
- `SequenceSource`: reach-avoid sequences drawn from a curriculum (DeepLTL's training tasks; with
  `continual=True`, GenZ-LTL's one-subgoal-at-a-time tasks: a completed sequence is replaced by a
  fresh draw and the episode goes on).
"""

from __future__ import annotations

import hashlib
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax import automata
from specrl_jax.specs import CurriculumSampler, ReachAvoidSequence
from specrl_jax.specs.curricula import ReachStay


class Events(NamedTuple):
    """What a task step did (bool[] each).

    `progress`: the current subgoal was achieved (automaton: left its state for a non-violating
    one or took an accepting transition; sequence: a pair completed). `accepted`: a Buchi-accepting
    transition. `success`: the task is complete (finite-horizon tasks). `violation`: an avoided
    assignment occurred, or the automaton entered a state with no satisfying continuation.
    """

    progress: jax.Array
    accepted: jax.Array
    success: jax.Array
    violation: jax.Array


class ByContent:
    """Arrays carried as static metadata of a task (`struct.field(pytree_node=False)`), compared
    by content (a digest of every leaf): equal contents share compilations and mix in a batch."""

    def __init__(self, tree: Any):
        self.tree = tree
        digest = hashlib.sha256()
        for leaf in jax.tree.leaves(tree):
            leaf = np.asarray(leaf)
            digest.update(f"{leaf.dtype}{leaf.shape}".encode())
            digest.update(leaf.tobytes())
        self.digest = digest.hexdigest()

    def __hash__(self) -> int:
        return hash(self.digest)

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.digest == other.digest

    def __repr__(self) -> str:  # names the content: tree-structure texts differ with it
        return f"{type(self).__qualname__}({self.digest})"


class SpecBank(ByContent):
    """The stacked specs that automaton tasks point into by `spec_index` (static metadata).

    Banks compare by content (a digest of every leaf), so tasks of two sources over equal specs
    mix and share compilations.
    """

    @property
    def specs(self) -> Any:
        return self.tree


@struct.dataclass
class AutomatonTask:
    """An episode's spec (an index into the bank) and automaton state."""

    spec_index: jax.Array  # int32[]
    q: jax.Array  # int32[], the run followed (it may have taken epsilon edges)
    q_free: jax.Array  # int32[], the run that never takes an epsilon edge (`fall_back_run`)
    bank: SpecBank = struct.field(pytree_node=False)

    @property
    def spec(self) -> Any:
        """The episode's `CompiledSpec`, read from the bank at `spec_index` (under `jit` only the
        entries a caller uses are gathered)."""
        return jax.tree.map(lambda leaf: leaf[self.spec_index], self.bank.specs)


def fall_back_run(stepped: tuple[jax.Array, ...], free: tuple[jax.Array, ...]
                  ) -> tuple[tuple[jax.Array, ...], jax.Array]:
    """The followed run's step outcome, or the never-jumping run's where only the former died.

    Our limit-deterministic automata (docs/automata.md, Translation 3) read every word on one
    epsilon-free run in their initial part, whose state has an empty language exactly when the
    formula is violated; a run that jumped into an accepting copy dies as soon as the word
    leaves what that copy guessed (for `F G x & G !y`: any step outside `x`, the empty label
    included), a wrong guess, not a violation. There the task continues on the epsilon-free
    run, and the agent may jump again: GenZ-LTL's set-of-states tracking, with the epsilon
    edges that its tracker leaves out (docs/fidelity.md).

    Args:
        stepped: `(q, accepted, success, violation)` of the followed run, int32[] / bool[] each.
        free: the same for the run that never jumped.

    Returns:
        The outcome the task takes, and `fell_back` bool[].
    """
    fell_back = stepped[3] & ~free[3]
    return tuple(jnp.where(fell_back, f, s) for s, f in zip(stepped, free)), fell_back


class AutomatonSource:
    """A stacked batch of `K` compiled specs; a reset without an index draws one uniformly.

    `fall_back` (default): a run that dies after an epsilon jump while the formula is still open
    returns to the run that never jumped (`fall_back_run`); off, the jumped run's death is a
    violation (DeepLTL's single-state tracker).
    """

    def __init__(self, specs: Any, alphabet: jax.Array, fall_back: bool = True):
        if not hasattr(specs, "delta") or jnp.ndim(specs.delta) != 3:
            raise ValueError(
                "specs must be a stacked batch of CompiledSpec (delta of shape [K, S, A]); "
                "use specrl_jax.automata.stack([...])"
            )
        spec_alphabet = np.asarray(specs.alphabet[0])
        env_alphabet = np.asarray(alphabet)
        if spec_alphabet.shape[1] != env_alphabet.shape[1]:
            raise ValueError(
                f"specs are over {spec_alphabet.shape[1]} propositions but the world has "
                f"{env_alphabet.shape[1]}; compile them with the world's propositions"
            )
        num_symbols = int(specs.delta.shape[2])
        if num_symbols != env_alphabet.shape[0]:
            raise ValueError(
                f"specs are compiled over {num_symbols} alphabet symbols but the world "
                f"has {env_alphabet.shape[0]}; compile them with alphabet=env.alphabet"
            )
        self.specs = specs
        self.bank = SpecBank(specs)
        self.num_tasks = int(specs.delta.shape[0])
        # the world's symbol is a row of its own alphabet: usable only where the specs' rows are
        # the same assignments in the same order (else the step looks the label up)
        self.symbol_is_row = bool(np.array_equal(spec_alphabet, env_alphabet))
        #: static: some spec has an epsilon edge (else the loop never keeps a world step back)
        self.may_take_epsilon = bool((np.asarray(specs.epsilon) >= 0).any())
        self.fall_back = fall_back

    def init_params(self) -> None:
        return None

    def reset(self, key: jax.Array, source_params: Any = None, index: jax.Array | None = None
              ) -> AutomatonTask:
        if index is None:
            index = jax.random.randint(key, (), 0, self.num_tasks)
        index = jnp.asarray(index, jnp.int32)
        init = self.specs.init[index].astype(jnp.int32)
        return AutomatonTask(index, init, init, self.bank)

    def next_index(self, task: AutomatonTask) -> jax.Array:
        """The spec of the next episode after `task`'s: the following one in the bank."""
        return (task.spec_index + 1) % self.num_tasks

    def takes_epsilon(self, task: AutomatonTask, slot: jax.Array) -> jax.Array:
        return automata.takes_epsilon(task.spec, task.q, slot)

    def step(self, key: jax.Array, task: AutomatonTask, props: jax.Array, symbol: jax.Array | None,
             is_epsilon: jax.Array, slot: jax.Array, source_params: Any = None
             ) -> tuple[AutomatonTask, Events]:
        symbol = symbol if self.symbol_is_row else None
        stepped = automata.step_in_batch(self.specs, task.spec_index, task.q, props,
                                         jnp.where(is_epsilon, slot, -1), symbol)
        q_free, fell_back = stepped[0], jnp.zeros((), bool)
        if self.may_take_epsilon and self.fall_back:  # static: only specs with epsilon edges
            free = automata.step_in_batch(self.specs, task.spec_index, task.q_free, props,
                                          jnp.int32(-1), symbol)
            free = tuple(jnp.where(is_epsilon, old, new)  # an epsilon step reads no label
                         for old, new in zip((task.q_free, False, False, False), free))
            stepped, fell_back = fall_back_run(stepped, free)
            q_free = free[0]
        q_next, accepted, success, violation = stepped
        success = success & self.specs.is_finite[task.spec_index]
        progress = ((q_next != task.q) | accepted) & ~violation & ~fell_back
        return task.replace(q=q_next, q_free=q_free), Events(progress, accepted, success, violation)


@struct.dataclass
class SequenceTask:
    """A reach-avoid sequence over alphabet symbols and how far it has been followed.

    Pairs `done <= i < pairs` remain; pair `i` is completed by a symbol of `reach[i]` (or by the
    epsilon action where `epsilon[i]`) and violated by a symbol of `avoid[i]`; the last pair
    repeats until `done == length`.
    """

    reach: jax.Array  # bool[L, A]
    avoid: jax.Array  # bool[L, A]
    epsilon: jax.Array  # bool[L]
    length: jax.Array  # int32[], pairs + repeats of the last pair
    pairs: jax.Array  # int32[], real pairs
    done: jax.Array  # int32[], pairs completed
    task_id: jax.Array  # int32[], the curriculum's task index (-1: sampled)

    @property
    def current(self) -> jax.Array:
        """int32[]: the pair being followed."""
        return jnp.minimum(self.done, self.pairs - 1)

    def current_masks(self, alphabet: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The current pair as proposition masks `(reach, avoid)`, bool[P] each, given the
        alphabet bool[A, P] (`proposition_masks`)."""
        current = self.current
        return (proposition_masks(self.reach[current], alphabet),
                proposition_masks(self.avoid[current], alphabet))


def proposition_masks(symbols: jax.Array, alphabet: jax.Array) -> jax.Array:
    """Symbol sets bool[..., A] -> proposition masks bool[..., P], the inverse of `symbol_sets`:
    the propositions every symbol of which is in the set. Where labels hold several propositions
    (moving zones may overlap), the set of `reach green` also holds `{green, blue}`, and blue is
    not to be reached."""
    outside = ~symbols[..., :, None] & alphabet  # [..., A, P]: a symbol of p left out
    return ~jnp.any(outside, axis=-2) & jnp.any(alphabet, axis=0)


def symbol_sets(props: jax.Array, alphabet: jax.Array, with_empty: jax.Array | None = None) -> jax.Array:
    """Proposition masks bool[..., P] -> symbol sets bool[..., A]: the symbols making some masked
    proposition true (and the empty symbol where `with_empty`)."""
    hit = jnp.any(props[..., None, :] & alphabet, axis=-1)
    if with_empty is None:
        return hit
    return hit | (with_empty[..., None] & ~jnp.any(alphabet, axis=-1))


class SequenceSource:
    """Reach-avoid sequences from a curriculum, over a world's alphabet.

    `continual=False` (DeepLTL): completing the sequence is the task's success. `continual=True`
    (GenZ-LTL): a completed sequence counts as progress only, and a fresh one is drawn that the
    current assignment leaves open; the episode ends on a violation or the horizon.
    """

    def __init__(self, sampler: CurriculumSampler, alphabet: jax.Array, continual: bool = False):
        alphabet = jnp.asarray(alphabet, bool)
        if sampler.num_props != alphabet.shape[1]:
            raise ValueError(
                f"the curriculum is over {sampler.num_props} propositions, the world has "
                f"{alphabet.shape[1]}"
            )
        self.sampler = sampler
        self.alphabet = alphabet
        self.continual = continual
        self.symbol_is_row = True
        self.may_take_epsilon = any(
            isinstance(sampler, ReachStay)
            for stage in sampler.curriculum.stages for sampler in stage.samplers)

    def init_params(self) -> Any:
        return self.sampler.init()

    def _draw(self, key: jax.Array, source_params: Any, current: jax.Array) -> SequenceTask:
        seq, task_id = self.sampler.sample(key, source_params, current)
        return self.from_sequence(seq, task_id)

    def from_sequence(self, seq: ReachAvoidSequence, task_id: jax.Array | int = -1) -> SequenceTask:
        """A task that follows `seq` from its first pair. A stay pair (`avoid_empty`) is also
        violated by every assignment without its reach proposition: with same-object twins
        (`sequences.twin_matrix`) its proposition set leaves the twin alone unavoided."""
        reach = symbol_sets(seq.reach, self.alphabet)
        avoid = symbol_sets(seq.avoid, self.alphabet, seq.avoid_empty)
        return SequenceTask(
            reach=reach,
            avoid=avoid | (seq.avoid_empty[..., None] & ~reach),
            epsilon=seq.epsilon,
            length=(seq.length + seq.repeat_last).astype(jnp.int32),
            pairs=jnp.asarray(seq.length, jnp.int32),
            done=jnp.zeros((), jnp.int32),
            task_id=jnp.asarray(task_id, jnp.int32),
        )

    def reset(self, key: jax.Array, source_params: Any = None, index: Any = None) -> SequenceTask:
        return self._draw(key, source_params, jnp.zeros(self.alphabet.shape[1], bool))

    def next_index(self, task: SequenceTask) -> None:
        return None

    def takes_epsilon(self, task: SequenceTask, slot: jax.Array) -> jax.Array:
        return (slot >= 0) & task.epsilon[task.current]

    def step(self, key: jax.Array, task: SequenceTask, props: jax.Array, symbol: jax.Array | None,
             is_epsilon: jax.Array, slot: jax.Array, source_params: Any = None
             ) -> tuple[SequenceTask, Events]:
        if symbol is None:
            symbol = automata.label_symbol(self.alphabet, props)
        current = task.current
        violation = ~is_epsilon & task.avoid[current, symbol]
        progress = jnp.where(is_epsilon, task.epsilon[current],
                             ~task.epsilon[current] & task.reach[current, symbol] & ~violation)
        task = task.replace(done=task.done + progress.astype(jnp.int32))
        complete = task.done >= task.length
        if self.continual:
            fresh = self._draw(key, source_params, props)
            task = jax.tree.map(lambda a, b: jnp.where(complete, a, b), fresh, task)
            complete = jnp.zeros((), bool)
        no = jnp.zeros((), bool)
        return task, Events(progress, no, complete, violation)
