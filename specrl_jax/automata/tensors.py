"""Compiled specs: an automaton and its subgoals as a pytree of arrays, and batching by padding."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.automata import cache, candidates, subgoals, translate

DEFAULT_MAX_SEQUENCES = 64
DEFAULT_MAX_LENGTH = 24
MAX_DEFAULT_ALPHABET_PROPS = 10


@struct.dataclass
class CompiledSpec:
    """One LTL spec over an alphabet of A assignments of P propositions (arrays only).

    Axes: S automaton states, A alphabet symbols, E epsilon slots, G one-step subgoals,
    C candidate sequences, L sequence steps, U distinct reach-avoid pairs of the sequences.
    Stacked specs carry a leading batch axis.

    Attributes:
        delta: int32[S, A] next state per alphabet symbol.
        accepting: bool[S, A] the transition q -a-> delta[q, a] is Buchi-accepting.
        epsilon: int32[S, E] epsilon successors, -1 padded.
        success: bool[S] every continuation satisfies the formula.
        violation: bool[S] no continuation satisfies it.
        init: int32[] initial state.
        is_finite: bool[] co-safe: the episode ends on success.
        alphabet: bool[A, P] the assignment of each symbol.
        subgoal_reach, subgoal_avoid: bool[S, G, A]; subgoal_target: int32[S, G] (-1 unused);
        subgoal_valid: bool[S, G]: one-step reach-avoid subgoals.
        seq_pair: int16[S, C, L] each step's pair (row of the pair table; 0, the empty
            padding pair, past the end); seq_length: int32[S, C]; seq_valid: bool[S, C]:
            DeepLTL's candidate sequences. `pairs(spec, spec.seq_pair[q, c])` gives the masks.
        seq_complete: bool[S] state q's candidates are the complete search's; False where the
            search was over its budget and they are shortest paths to acceptance only.
        pair_reach, pair_avoid: bool[U, A] symbols to reach / avoid (reach empty for epsilon);
        pair_epsilon_slot: int32[U] epsilon edge to take, -1 if not an epsilon step.
        step_table: int32[S, A + 1 + E] every step outcome packed in one word (`pack_step_table`):
            column a < A reads symbol a, column A an unknown label (stay), column A + 1 + e
            epsilon slot e (stay where the slot is empty). Derived from the fields above.
        symbol_of_code: int8/int16[2**P] the symbol of each label read as a binary number
            (A where the label is not in the alphabet); empty if P > 12. Derived from `alphabet`.
        step_planes: uint32[A + 1 + E, K] `step_table` as bit-planes over the states
            (`pack_step_planes`) for automata of at most 32 states; [A + 1 + E, 0] otherwise.
    """

    delta: jnp.ndarray
    accepting: jnp.ndarray
    epsilon: jnp.ndarray
    success: jnp.ndarray
    violation: jnp.ndarray
    init: jnp.ndarray
    is_finite: jnp.ndarray
    alphabet: jnp.ndarray
    subgoal_reach: jnp.ndarray
    subgoal_avoid: jnp.ndarray
    subgoal_target: jnp.ndarray
    subgoal_valid: jnp.ndarray
    seq_pair: jnp.ndarray
    seq_length: jnp.ndarray
    seq_valid: jnp.ndarray
    seq_complete: jnp.ndarray
    pair_reach: jnp.ndarray
    pair_avoid: jnp.ndarray
    pair_epsilon_slot: jnp.ndarray
    step_table: jnp.ndarray
    symbol_of_code: jnp.ndarray
    step_planes: jnp.ndarray

    @property
    def num_states(self) -> int:
        return self.delta.shape[-2]

    @property
    def nbytes(self) -> int:
        """Bytes of all arrays together."""
        return sum(int(np.asarray(x).nbytes) for x in self.__dict__.values())


FIELDS = tuple(CompiledSpec.__dataclass_fields__)
_DERIVED = ("step_table", "symbol_of_code", "step_planes")
MAX_CODE_TABLE_PROPS = 12
_STORED = tuple(f for f in FIELDS if f not in _DERIVED)
_CACHED = _STORED + ("seq_dropped",)  # int32[]: candidates dropped by the caps, for the warning

STATE_MASK = (1 << 28) - 1
ACCEPTED_BIT = 1 << 28
SUCCESS_BIT = 1 << 29
VIOLATION_BIT = 1 << 30


def symbol_of_code(alphabet: np.ndarray) -> np.ndarray:
    """int8/int16[2**P]: code -> symbol, A for a label outside the alphabet ([0] if P > 12)."""
    num_symbols, num_props = alphabet.shape
    dtype = np.int8 if num_symbols < 128 else np.int16
    if num_props > MAX_CODE_TABLE_PROPS:
        return np.zeros((0,), dtype)
    table = np.full(1 << num_props, num_symbols, dtype)
    table[(alphabet.astype(np.int64) << np.arange(num_props)).sum(-1)] = np.arange(num_symbols)
    return table


def pack_step_table(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """int32[S, A + 1 + E]: next state | accepted << 28 | success << 29 | violation << 30.

    The flags are those of the transition (accepted) and of the state it leads to, so one
    gather answers a whole `step`.
    """
    delta, epsilon = arrays["delta"], arrays["epsilon"]
    num_states = delta.shape[0]
    stay = np.arange(num_states)
    eps_next = np.where(epsilon >= 0, epsilon, stay[:, None])
    nxt = np.concatenate([delta, stay[:, None], eps_next], axis=1).astype(np.int64)
    accepted = np.concatenate([arrays["accepting"], np.zeros_like(eps_next[:, :1], bool),
                               np.zeros_like(eps_next, bool)], axis=1)
    packed = (nxt | accepted * ACCEPTED_BIT | arrays["success"][nxt] * SUCCESS_BIT
              | arrays["violation"][nxt] * VIOLATION_BIT)
    return packed.astype(np.int32)


MAX_PLANE_STATES = 32


def pack_step_planes(step_table: np.ndarray) -> np.ndarray:
    """uint32[..., W, K]: a packed `step_table` int32[..., S, W] turned into bit-planes over the
    states (any leading axes, e.g. a stack).

    Bit q of `planes[c, k]` is bit k of the outcome of state q on column c: first the
    ceil(log2 S) bits of the next state, then accepted, success, violation (K = those + 3). A
    step then reads one row by column alone and shifts it by q, so the state is only read
    elementwise and XLA can update a loop-carried state in place, in the kernel that computes
    it (a gather indexed by q cannot). Only for S <= 32; more states give [..., W, 0] and the
    step reads `step_table` instead.
    """
    *lead, num_states, width = step_table.shape
    if num_states > MAX_PLANE_STATES:
        return np.zeros((*lead, width, 0), np.uint32)
    words = step_table.astype(np.int64)
    state_bits = max(1, (num_states - 1).bit_length())
    fields = [((words & STATE_MASK) >> k) & 1 for k in range(state_bits)]
    fields += [(words & flag) != 0 for flag in (ACCEPTED_BIT, SUCCESS_BIT, VIOLATION_BIT)]
    shifts = np.arange(num_states, dtype=np.uint64)[:, None]
    planes = [(field.astype(np.uint64) << shifts).sum(axis=-2) for field in fields]
    return np.stack(planes, axis=-1).astype(np.uint32)


class Pairs(NamedTuple):
    """Reach-avoid pairs gathered from the pair table (`pairs`), `...` = the shape of the ids."""

    reach: jnp.ndarray  # bool[..., A]
    avoid: jnp.ndarray  # bool[..., A]
    epsilon: jnp.ndarray  # bool[...], an epsilon step
    epsilon_slot: jnp.ndarray  # int32[...], the epsilon edge to take, -1 if none


def pairs(spec: CompiledSpec, ids: jnp.ndarray) -> Pairs:
    """The masks of pair ids of one (unstacked) spec, e.g. `pairs(spec, spec.seq_pair[q, c])`
    for candidate c in state q: reach/avoid bool[L, A], epsilon bool[L], epsilon_slot int32[L].
    Works inside `jit`/`vmap` (three gathers)."""
    slot = spec.pair_epsilon_slot[ids]
    return Pairs(spec.pair_reach[ids], spec.pair_avoid[ids], slot >= 0, slot)


def compile_spec(
    formula: str,
    propositions: Sequence[str],
    alphabet: np.ndarray | None = None,
    *,
    max_sequences: int = DEFAULT_MAX_SEQUENCES,
    max_length: int = DEFAULT_MAX_LENGTH,
    use_cache: bool = True,
) -> CompiledSpec:
    """Translate an LTL formula (Spot syntax) into a `CompiledSpec` over `alphabet`.

    Args:
        formula: e.g. "!(a | b) U (c & F d)"; `=>`/`<=>` are read as `->`/`<->`.
        propositions: the env's proposition names, in `info["propositions"]` order.
        alphabet: bool[A, P], the assignments the world can produce (`env.alphabet`); default
            all 2**P subsets (only for P <= 10).
        max_sequences, max_length: caps C and L of the candidate sequences (see
            `candidates.candidate_sequences` for what happens past them).
        use_cache: read and write the disk cache (`cache.cache_dir()`).

    Raises:
        ValueError / TypeError: bad formula, proposition, alphabet, or an unsatisfiable formula.

    Warns:
        UserWarning: the candidate search was incomplete for some states (`seq_complete`), or
            candidates were dropped by the caps; again whenever the spec comes from the cache.
    """
    propositions = tuple(propositions)
    if len(set(propositions)) != len(propositions) or not propositions:
        raise ValueError(f"propositions must be distinct names, got {propositions}")
    if alphabet is None:
        if len(propositions) > MAX_DEFAULT_ALPHABET_PROPS:
            raise ValueError(f"{len(propositions)} propositions: pass the env's alphabet (all "
                             f"subsets are only the default up to {MAX_DEFAULT_ALPHABET_PROPS})")
        alphabet = translate.all_subsets(len(propositions))
    alphabet = translate.check_alphabet(alphabet, propositions)
    if max_sequences < 1 or max_length < 1:
        raise ValueError(f"max_sequences and max_length must be >= 1, got "
                         f"{max_sequences}, {max_length}")
    key = cache.cache_key(formula if isinstance(formula, str) else repr(formula), propositions,
                          alphabet, max_sequences=max_sequences, max_length=max_length)
    arrays = cache.load(key) if use_cache else None
    if arrays is None or set(arrays) != set(_CACHED):
        arrays = _build(formula, propositions, alphabet, max_sequences, max_length)
        if use_cache:
            cache.save(key, arrays)
    _warn_search(arrays, max_sequences, max_length)
    arrays = _with_derived({name: np.asarray(arrays[name]) for name in _STORED})
    # device_put is a plain copy; jnp.asarray would dispatch (and compile) one op per shape
    return CompiledSpec(**jax.device_put(arrays))


def _build(formula, propositions, alphabet, max_sequences, max_length) -> dict[str, np.ndarray]:
    aut = translate.translate(formula, propositions, alphabet)
    goals = subgoals.one_step_subgoals(aut)
    seqs = candidates.candidate_sequences(aut, max_sequences, max_length)
    return {
        "delta": aut.delta.astype(np.int32),
        "accepting": aut.accepting,
        "epsilon": aut.epsilon.astype(np.int32),
        "success": aut.success,
        "violation": aut.violation,
        "init": np.int32(aut.init),
        "is_finite": np.bool_(aut.is_finite),
        "alphabet": alphabet,
        "subgoal_reach": goals.reach,
        "subgoal_avoid": goals.avoid,
        "subgoal_target": goals.target,
        "subgoal_valid": goals.valid,
        "seq_pair": seqs.pair,
        "seq_length": seqs.length,
        "seq_valid": seqs.valid,
        "seq_complete": seqs.complete,
        "seq_dropped": np.int32(seqs.dropped.sum()),
        "pair_reach": seqs.pair_reach,
        "pair_avoid": seqs.pair_avoid,
        "pair_epsilon_slot": seqs.pair_epsilon_slot,
    }


def _with_derived(stored: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """`stored` (the `_STORED` fields of one spec, or of a stack along a leading axis) with the
    `_DERIVED` fields added: `step_table`, `symbol_of_code`, `step_planes`."""
    out = dict(stored)
    if stored["delta"].ndim == 3:  # a stack: the per-spec tables, one shared alphabet
        out["step_table"] = np.stack([
            pack_step_table({name: stored[name][i] for name in _STORED})
            for i in range(stored["delta"].shape[0])])
        out["symbol_of_code"] = np.stack(
            [symbol_of_code(stored["alphabet"][0])] * stored["delta"].shape[0])
    else:
        out["step_table"] = pack_step_table(stored)
        out["symbol_of_code"] = symbol_of_code(stored["alphabet"])
    out["step_planes"] = pack_step_planes(out["step_table"])
    return out


def _warn_search(arrays: dict[str, np.ndarray], max_sequences: int, max_length: int) -> None:
    """The warnings of an incomplete candidate search, built or loaded from the cache alike."""
    complete = np.asarray(arrays["seq_complete"])
    if not complete.all():
        warnings.warn(f"the complete candidate search was over its budget from "
                      f"{int((~complete).sum())} of {complete.size} automaton states; their "
                      "candidates are shortest paths to acceptance only (see docs/automata.md)",
                      stacklevel=3)
    dropped = int(arrays["seq_dropped"])
    if dropped:
        warnings.warn(f"{dropped} candidate sequences dropped (over max_length={max_length} "
                      f"or max_sequences={max_sequences} per state)", stacklevel=3)


# per field: which axes are padded, to which common size (by axis letter), and with what value
_PAD = {
    "delta": ("S", -1), "accepting": ("S", False), "epsilon": ("SE", -1),
    "success": ("S", False), "violation": ("S", False), "init": ("", 0),
    "is_finite": ("", False), "alphabet": ("", False),
    "subgoal_reach": ("SG", False), "subgoal_avoid": ("SG", False),
    "subgoal_target": ("SG", -1), "subgoal_valid": ("SG", False),
    "seq_pair": ("SCL", 0), "seq_length": ("SC", 0), "seq_valid": ("SC", False),
    "seq_complete": ("S", True),
    "pair_reach": ("U", False), "pair_avoid": ("U", False), "pair_epsilon_slot": ("U", -1),
}
_AXIS = {"S": ("delta", 0), "E": ("epsilon", 1), "G": ("subgoal_target", 1),
         "C": ("seq_length", 1), "L": ("seq_pair", 2), "U": ("pair_epsilon_slot", 0)}


def stack(specs: Sequence[CompiledSpec]) -> CompiledSpec:
    """Pad specs to common S, E, G, C, L, U and stack them along a new leading axis.

    Padded states are non-accepting self-loops with every flag False; padded epsilon slots are
    -1, padded subgoals and sequences are invalid, padded sequence steps name pair 0 (the
    empty pair) and padded pairs are empty. All specs must share one alphabet.
    """
    specs = list(specs)
    if not specs:
        raise ValueError("stack needs at least one CompiledSpec")
    alphabet = np.asarray(specs[0].alphabet)
    for i, spec in enumerate(specs):
        if not isinstance(spec, CompiledSpec) or spec.delta.ndim != 2:
            raise TypeError(f"stack takes unstacked CompiledSpecs; item {i} is not one")
        if not np.array_equal(np.asarray(spec.alphabet), alphabet):
            raise ValueError(f"spec {i} has a different alphabet from spec 0; specs stacked "
                             "together must be compiled over the same alphabet")
    size = {ax: max(np.shape(getattr(s, f))[d] for s in specs) for ax, (f, d) in _AXIS.items()}
    out = {}
    for name in _STORED:
        axes, fill = _PAD[name]
        padded = []
        for spec in specs:
            arr = np.asarray(getattr(spec, name))
            widths = [(0, 0)] * arr.ndim
            for ax in axes:
                d = _AXIS[ax][1]
                widths[d] = (0, size[ax] - arr.shape[d])
            if axes:
                arr = np.pad(arr, widths, constant_values=fill)
            if name == "delta":
                extra = np.arange(spec.num_states, size["S"])
                arr[extra] = extra[:, None]
            padded.append(arr)
        out[name] = np.stack(padded)
    return CompiledSpec(**jax.device_put(_with_derived(out)))


def compile_suite(formulas: Sequence[str], propositions: Sequence[str],
                  alphabet: np.ndarray | jax.Array) -> CompiledSpec:
    """The one way to compile several formulas into one stacked bank: `compile_spec` of each
    over `propositions` and `alphabet` (e.g. a world's `env.propositions`, `env.alphabet`), then
    `stack`. The leading axis follows `formulas`."""
    return stack([compile_spec(f, tuple(propositions), alphabet=alphabet) for f in formulas])
