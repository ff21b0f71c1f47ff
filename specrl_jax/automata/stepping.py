"""Stepping a compiled spec inside `jit`: label -> alphabet symbol -> next automaton state.

All functions are pure and take one unstacked `CompiledSpec`; `jax.vmap` them over a stacked
batch (`stack`) together with states and labels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import checkify

from specrl_jax.automata.tensors import (
    ACCEPTED_BIT,
    STATE_MASK,
    SUCCESS_BIT,
    VIOLATION_BIT,
    CompiledSpec,
)


def symbol_index(spec: CompiledSpec, props: jax.Array) -> jax.Array:
    """The alphabet row equal to a label.

    Args:
        spec: a compiled spec.
        props: bool[P] the propositions that hold (`info["propositions"]`).

    Returns:
        int32[], the matching row of `spec.alphabet`, or -1 if the label is not in the alphabet
        (use `step_checked` or `check_labels` to turn that into an error).
    """
    match = _matches(spec.alphabet, props)
    return jnp.where(match.any(), jnp.argmax(match), -1).astype(jnp.int32)


def _matches(alphabet: jax.Array, props: jax.Array) -> jax.Array:
    """bool[..., A]: which alphabet rows equal the label(s) `props` bool[..., P]."""
    return jnp.all(alphabet == props.astype(bool)[..., None, :], axis=-1)


def label_symbol(alphabet: jax.Array, props: jax.Array) -> jax.Array:
    """int32[...]: the alphabet row of each label `props` bool[..., P] (row 0 for a label outside
    the alphabet, which a world never produces; `symbol_index` tells that case apart)."""
    return jnp.argmax(_matches(alphabet, props), axis=-1).astype(jnp.int32)


def has_epsilon(spec: CompiledSpec, q: jax.Array) -> jax.Array:
    """bool[]: state `q` has at least one epsilon transition (mask for an epsilon action)."""
    return spec.epsilon[q, 0] >= 0


def takes_epsilon(spec: CompiledSpec, q: jax.Array, take_epsilon: jax.Array | bool | int
                  ) -> jax.Array:
    """bool[]: `step(spec, q, _, take_epsilon)` takes an epsilon edge (the slot asked for exists
    in state `q`; otherwise the step reads the label)."""
    slot = epsilon_slot(take_epsilon)
    num_slots = spec.epsilon.shape[-1]
    return ((slot >= 0) & (slot < num_slots)
            & (spec.epsilon[q, jnp.clip(slot, 0, num_slots - 1)] >= 0))


def epsilon_slot(take_epsilon: jax.Array | bool | int) -> jax.Array:
    """int32[]: the epsilon slot asked for; a bool means slot 0 (True) or none (False), an
    integer is the slot itself, and any negative value means none."""
    take = jnp.asarray(take_epsilon)
    if take.dtype == jnp.bool_:
        return jnp.where(take, 0, -1).astype(jnp.int32)
    return take.astype(jnp.int32)


UNROLL_MAX_SYMBOLS = 64
CODE_MAX_PROPS = 30  # labels as int32 codes; wider labels are compared bit by bit


def _code(bits: jax.Array) -> jax.Array:
    """int32[...]: bool[..., P] read as a binary number."""
    weights = jnp.left_shift(1, jnp.arange(bits.shape[-1], dtype=jnp.int32))
    return jnp.sum(jnp.where(bits.astype(bool), weights, 0), axis=-1)


def _column(alphabet: jax.Array, symbol_of_code: jax.Array, num_slots: int, props: jax.Array,
            take_epsilon, symbol: jax.Array | None = None) -> jax.Array:
    """int32[]: the `step_table` column of a step (symbol, unknown label, or epsilon slot; a
    slot past the last one is a slot the state lacks, so it stays). `symbol`, when given, is the
    label's alphabet row as the env reports it, and `props` is not read."""
    num_symbols, num_props = alphabet.shape
    slot = epsilon_slot(take_epsilon)
    if symbol is not None:
        symbol = jnp.asarray(symbol, jnp.int32)
        symbol = jnp.where((symbol >= 0) & (symbol < num_symbols), symbol, num_symbols)
    elif symbol_of_code.shape[-1] == 1 << num_props:
        # a gather fuses with the env's own kernels; a search over the alphabet adds its own
        symbol = symbol_of_code[_code(props)].astype(jnp.int32)
    elif num_symbols <= UNROLL_MAX_SYMBOLS and num_props <= CODE_MAX_PROPS:
        code, codes = _code(props), _code(alphabet)
        symbol = jnp.int32(num_symbols)
        for a in range(num_symbols):
            symbol = jnp.where(code == codes[a], a, symbol)
    else:
        match = _matches(alphabet, props)
        symbol = jnp.where(match.any(), jnp.argmax(match), num_symbols)
    eps_column = jnp.where(slot < num_slots, num_symbols + 1 + slot, num_symbols)
    return jnp.where(slot >= 0, eps_column, symbol).astype(jnp.int32)


def _unpack(word: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    return (word & STATE_MASK, (word & ACCEPTED_BIT) != 0, (word & SUCCESS_BIT) != 0,
            (word & VIOLATION_BIT) != 0)


def _from_planes(planes: jax.Array, q: jax.Array
                 ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The outcome of state q from its column's bit-planes uint32[K] (`pack_step_planes`)."""
    shift = jnp.asarray(q).astype(jnp.uint32)
    bits = [(planes[..., k] >> shift) & 1 for k in range(planes.shape[-1])]
    # unrolled rather than a reduction over K, so that the step stays one elementwise kernel
    q_next = sum(bits[k].astype(jnp.int32) << k for k in range(len(bits) - 3))
    return (q_next.astype(jnp.int32),) + tuple(b == 1 for b in bits[-3:])


def _outcome(spec: CompiledSpec, which: tuple, q: jax.Array, column: jax.Array
             ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """State q's outcome on `column`, from the bit-planes when the spec has them (<= 32 states),
    else from the packed words; `which` indexes the spec in a stack (`()` for one spec)."""
    if spec.step_planes.shape[-1]:
        return _from_planes(spec.step_planes[(*which, column)], q)
    return _unpack(spec.step_table[(*which, q, column)])


def step(
    spec: CompiledSpec,
    q: jax.Array,
    props: jax.Array,
    take_epsilon: jax.Array,
    symbol: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """One automaton step (one gather from `spec.step_planes`, or `spec.step_table` for
    automata of more than 32 states).

    Args:
        spec: a compiled spec.
        q: int32[] current state.
        props: bool[P] the label after the env step (ignored on an epsilon step).
        take_epsilon: bool[] (True = epsilon slot 0) or int32[] (slot to take, < 0 = none).
            An epsilon step consumes no label; requesting a slot the state lacks leaves q.
        symbol: optional int32[], the row of `spec.alphabet` equal to `props`, where the env
            reports it (`info["symbol"]`); the step then skips the label lookup (`props` is not
            read), and a value outside 0..A-1 acts as a label outside the alphabet. It must
            agree with `props` (`step_checked` verifies it).

    Returns:
        (q_next int32[], accepted bool[] (a Buchi-accepting transition was taken),
         success bool[], violation bool[]) where success / violation are flags of q_next.
        A label outside the alphabet leaves q unchanged in this unchecked variant.
    """
    column = _column(spec.alphabet, spec.symbol_of_code, spec.epsilon.shape[-1], props,
                     take_epsilon, symbol)
    return _outcome(spec, (), q, column)


def step_in_batch(
    specs: CompiledSpec,
    spec_id: jax.Array,
    q: jax.Array,
    props: jax.Array,
    take_epsilon: jax.Array,
    symbol: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """`step` on spec `spec_id` of a stacked batch, reading only the word it needs.

    Equal to `step(jax.tree.map(lambda x: x[spec_id], specs), q, props, take_epsilon)`, but
    under `vmap` over environments it gathers one entry instead of whole tables.

    Args:
        specs: stacked specs (`stack`), one shared alphabet.
        spec_id: int32[] which spec.
        q, props, take_epsilon, symbol: as in `step`.
    """
    column = _column(specs.alphabet[0], specs.symbol_of_code[0], specs.epsilon.shape[-1],
                     props, take_epsilon, symbol)
    return _outcome(specs, (spec_id,), q, column)


def step_checked(
    spec: CompiledSpec,
    q: jax.Array,
    props: jax.Array,
    take_epsilon: jax.Array,
    symbol: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """`step` that raises (through `jax.experimental.checkify`) on a label outside the alphabet,
    or on a `symbol` that is not the alphabet row of `props`.

    Use as `checkify.checkify(jax.jit(step_checked))(...)` (then `err.throw()`), or eagerly.
    """
    labelled = epsilon_slot(take_epsilon) < 0
    row = symbol_index(spec, props)
    checkify.check(
        ~labelled | (row >= 0),
        "label {} is not an assignment of the spec's alphabet",
        props.astype(jnp.int32),
    )
    if symbol is not None:
        symbol = jnp.asarray(symbol, jnp.int32)
        checkify.check(
            ~labelled | (symbol == row),
            "symbol {} is not the alphabet row {} of label {}",
            symbol, row, props.astype(jnp.int32),
        )
    return step(spec, q, props, take_epsilon, symbol)


def check_labels(spec: CompiledSpec, props: np.ndarray) -> None:
    """Host-side check that every label (`bool[..., P]`) is a row of the spec's alphabet.

    Raises:
        ValueError: naming the first label that is not.
    """
    labels = np.asarray(props).astype(bool)
    alphabet = np.asarray(spec.alphabet)
    if labels.shape[-1] != alphabet.shape[-1]:
        raise ValueError(f"labels have {labels.shape[-1]} propositions, the spec "
                         f"{alphabet.shape[-1]}")
    flat = labels.reshape(-1, labels.shape[-1])
    found = (flat[:, None, :] == alphabet[None, :, :]).all(-1).any(-1)
    if not found.all():
        bad = flat[np.argmin(found)].astype(int).tolist()
        raise ValueError(f"label {bad} is not an assignment of the spec's alphabet "
                         f"({alphabet.shape[0]} assignments)")
