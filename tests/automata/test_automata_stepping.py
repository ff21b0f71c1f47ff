"""Stepping: batched equals unbatched, padding changes nothing, checked mode, epsilon moves."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import checkify

from specrl_jax.automata import (
    check_labels,
    compile_spec,
    has_epsilon,
    stack,
    step,
    step_checked,
    step_in_batch,
    symbol_index,
    zero_or_one,
)

PROPS = ("a", "b", "c", "d")
FORMULAS = ["!a U (b & F c)", "GF a & GF b & G !d", "FG a & F(b & F c)", "FG a | GF b",
            "(F b) & (!(c | d) U (a & F b))"]


def _rollout(spec, syms, eps):
    """Unbatched reference: Python loop over `step`, one spec at a time."""
    q, out = spec.init, []
    for sym, e in zip(syms, eps):
        q, acc, succ, viol = step(spec, q, spec.alphabet[sym], e)
        out.append((int(q), bool(acc), bool(succ), bool(viol)))
    return out


def test_batched_padded_stepping_equals_unbatched():
    alphabet = zero_or_one(4)
    specs = [compile_spec(f, PROPS, alphabet) for f in FORMULAS]
    batch = stack(specs)
    assert batch.delta.shape[0] == len(FORMULAS)
    rng = np.random.default_rng(0)
    steps = 12
    syms = rng.integers(5, size=(len(specs), steps))
    eps = rng.random((len(specs), steps)) < 0.2

    @jax.jit
    def run(batch, syms, eps):
        def body(q, inp):
            sym, e = inp
            props = jax.vmap(lambda a, s: a[s])(batch.alphabet, sym)
            q, acc, succ, viol = jax.vmap(step)(batch, q, props, e)
            return q, (q, acc, succ, viol)

        return jax.lax.scan(body, batch.init, (syms.T, eps.T))[1]

    @jax.jit
    def run_in_batch(batch, syms, eps):
        ids = jnp.arange(len(specs))

        def body(q, inp):
            sym, e = inp
            props = batch.alphabet[0][sym]
            out = jax.vmap(step_in_batch, (None, 0, 0, 0, 0))(batch, ids, q, props, e)
            return out[0], out

        return jax.lax.scan(body, batch.init, (syms.T, eps.T))[1]

    got = [np.asarray(x).T for x in run(batch, jnp.asarray(syms), jnp.asarray(eps))]
    got_ids = [np.asarray(x).T for x in run_in_batch(batch, jnp.asarray(syms), jnp.asarray(eps))]
    for k, spec in enumerate(specs):
        expect = _rollout(spec, syms[k], eps[k])
        assert [tuple(x[k, t].item() for x in got) for t in range(steps)] == expect
        assert [tuple(x[k, t].item() for x in got_ids) for t in range(steps)] == expect


def test_padding_states_are_inert():
    specs = [compile_spec(f, PROPS, zero_or_one(4)) for f in FORMULAS]
    batch = stack(specs)
    small = int(np.argmin([s.num_states for s in specs]))
    padded = jax.tree.map(lambda x: x[small], batch)
    extra = np.arange(specs[small].num_states, batch.delta.shape[1])
    assert len(extra) > 0
    delta = np.asarray(padded.delta)
    assert (delta[extra] == extra[:, None]).all()
    for field in ("accepting", "success", "violation", "seq_valid", "subgoal_valid"):
        assert not np.asarray(getattr(padded, field))[extra].any()
    assert (np.asarray(padded.epsilon)[extra] == -1).all()
    # real states never lead into padding
    assert (delta[: specs[small].num_states] < specs[small].num_states).all()


def test_stack_rejects_mixed_alphabets():
    a = compile_spec("F a", PROPS, zero_or_one(4))
    b = compile_spec("F a", ("a", "b", "c", "e"), zero_or_one(4)[::-1].copy())
    with pytest.raises(ValueError, match="different alphabet"):
        stack([a, b])


def test_symbol_index_and_checked_mode():
    spec = compile_spec("F a", PROPS, zero_or_one(4))
    for row in range(5):
        assert int(symbol_index(spec, spec.alphabet[row])) == row
    two = jnp.array([True, True, False, False])
    assert int(symbol_index(spec, two)) == -1
    for no_epsilon in (False, jnp.int32(-1)):  # a bool or a negative slot: no epsilon move
        err, _ = checkify.checkify(jax.jit(step_checked))(spec, spec.init, two, no_epsilon)
        with pytest.raises(checkify.JaxRuntimeError, match="not an assignment"):
            err.throw()
    err, out = checkify.checkify(jax.jit(step_checked))(spec, spec.init, spec.alphabet[1], False)
    err.throw()
    assert bool(out[2])  # F a: success after a
    with pytest.raises(ValueError, match=r"label \[1, 1, 0, 0\]"):
        check_labels(spec, np.array([[0, 1, 0, 0], [1, 1, 0, 0]], dtype=bool))


def test_checked_mode_verifies_the_env_symbol():
    spec = compile_spec("F a", PROPS, zero_or_one(4))
    checked = checkify.checkify(jax.jit(step_checked))
    err, out = checked(spec, spec.init, spec.alphabet[1], False, jnp.int32(1))
    err.throw()
    assert bool(out[2])
    err, _ = checked(spec, spec.init, spec.alphabet[1], False, jnp.int32(2))
    with pytest.raises(checkify.JaxRuntimeError, match="symbol 2 is not the alphabet row 1"):
        err.throw()
    err, _ = checked(spec, spec.init, spec.alphabet[1], True, jnp.int32(2))  # epsilon: unread
    err.throw()
    # unchecked, the step follows the symbol and does not read the label
    assert bool(step(spec, spec.init, spec.alphabet[2], False, jnp.int32(1))[2])
    assert not bool(step(spec, spec.init, spec.alphabet[1], False, jnp.int32(2))[2])


def test_epsilon_moves_consume_no_label():
    spec = compile_spec("FG a", PROPS, zero_or_one(4))
    q0 = spec.init
    assert bool(has_epsilon(spec, q0))
    nothing, a, b = spec.alphabet[0], spec.alphabet[1], spec.alphabet[2]
    q1, acc, _, viol = step(spec, q0, b, True)  # the label is ignored on an epsilon step
    assert int(q1) != int(q0) and not bool(acc) and not bool(viol)
    assert not bool(has_epsilon(spec, q1))
    q2, acc, _, viol = step(spec, q1, a, False)
    assert int(q2) == int(q1) and bool(acc) and not bool(viol)
    _, acc, _, viol = step(spec, q1, nothing, False)
    assert bool(viol) and not bool(acc)
    # epsilon requested where there is none: no move
    q3, acc, _, _ = step(spec, q1, a, jnp.int32(0))
    assert int(q3) == int(q1) and not bool(acc)


@pytest.mark.parametrize("lookup", ["code_table", "unrolled", "reduction", "packed_words"])
def test_step_table_agrees_with_the_automaton_tables(monkeypatch, lookup):
    """Every (state, label or epsilon slot) read from the bit-planes (or, past 32 states, the
    packed words) gives the same next state and flags as delta / accepting / epsilon / success /
    violation, on each label lookup."""
    from specrl_jax.automata import stepping

    spec = compile_spec("FG a | GF b & GF c", PROPS, zero_or_one(4))
    assert spec.step_planes.shape[-1] == max(1, (spec.num_states - 1).bit_length()) + 3
    if lookup in ("unrolled", "reduction"):  # the code table is left out for P > 12
        spec = spec.replace(symbol_of_code=spec.symbol_of_code[:0])
    if lookup == "packed_words":  # the planes are left out for S > 32
        spec = spec.replace(step_planes=spec.step_planes[:, :0])
    if lookup == "reduction":
        monkeypatch.setattr(stepping, "UNROLL_MAX_SYMBOLS", 0)
    delta, accepting = np.asarray(spec.delta), np.asarray(spec.accepting)
    epsilon, success, violation = (np.asarray(spec.epsilon), np.asarray(spec.success),
                                   np.asarray(spec.violation))
    assert (epsilon >= 0).sum() >= 2
    unknown = np.array([True, True, False, False])  # two propositions at once: not in the alphabet
    labels = np.concatenate([np.asarray(spec.alphabet), unknown[None]])
    num_states, num_slots = delta.shape[0], epsilon.shape[1]
    qs, rows, slots = np.meshgrid(np.arange(num_states), np.arange(len(labels)),
                                  np.arange(-1, num_slots + 1), indexing="ij")
    qs, rows, slots = qs.ravel(), rows.ravel(), slots.ravel()
    got = jax.jit(jax.vmap(step, (None, 0, 0, 0)))(spec, qs, labels[rows], slots)
    got = [np.asarray(x) for x in got]
    sym = np.minimum(rows, delta.shape[1] - 1)
    known = rows < delta.shape[1]
    eps_target = np.where(slots < num_slots, epsilon[qs, np.clip(slots, 0, num_slots - 1)], -1)
    label_next = np.where(known, delta[qs, sym], qs)
    want_q = np.where(slots >= 0, np.where(eps_target >= 0, eps_target, qs), label_next)
    want_acc = (slots < 0) & known & accepting[qs, sym]
    np.testing.assert_array_equal(got[0], want_q)
    np.testing.assert_array_equal(got[1], want_acc)
    np.testing.assert_array_equal(got[2], success[want_q])
    np.testing.assert_array_equal(got[3], violation[want_q])


def test_step_planes_cover_up_to_32_states():
    """Bit-planes are packed for 32 states (shifts 0..31 of a uint32) and left out past that."""
    from specrl_jax.automata.tensors import pack_step_planes

    rng = np.random.default_rng(0)
    for num_states in (1, 2, 32, 33):
        table = rng.integers(0, num_states, (num_states, 5)).astype(np.int32)
        table |= rng.integers(0, 8, table.shape).astype(np.int32) << 28
        planes = pack_step_planes(table)
        if num_states > 32:
            assert planes.shape == (5, 0)
            continue
        q = np.arange(num_states)[:, None]
        bits = (planes[None].astype(np.int64) >> q[..., None]) & 1  # [S, W, K]
        state_bits = planes.shape[-1] - 3
        assert ((bits[..., :state_bits] << np.arange(state_bits)).sum(-1)
                == table & ((1 << 28) - 1)).all()
        for k in range(3):
            assert (bits[..., state_bits + k] == (table >> (28 + k)) & 1).all()


@pytest.mark.parametrize("num_states", [31, 32, 33])
def test_step_reads_the_same_outcome_from_planes_and_words(num_states):
    """`step` on random packed words of S states: the bit-plane path (S <= 32; the shift by
    q = 31 uses the top bit) and the word path give every word's outcome, from the label or
    from the symbol; a plain int state works on both."""
    from specrl_jax.automata.tensors import pack_step_planes

    spec = compile_spec("F a", PROPS, zero_or_one(4))
    num_columns = spec.step_table.shape[-1]
    rng = np.random.default_rng(num_states)
    table = rng.integers(0, num_states, (num_states, num_columns)).astype(np.int32)
    table |= rng.integers(0, 8, table.shape).astype(np.int32) << 28
    planes = pack_step_planes(table)
    assert planes.shape[-1] == (0 if num_states > 32 else (num_states - 1).bit_length() + 3)
    with_planes = spec.replace(step_table=jnp.asarray(table), step_planes=jnp.asarray(planes))
    words_only = with_planes.replace(step_planes=with_planes.step_planes[:, :0])
    labels = np.asarray(spec.alphabet)
    qs, rows = np.meshgrid(np.arange(num_states), np.arange(len(labels)), indexing="ij")
    qs, rows = qs.ravel(), rows.ravel()
    want = (table[qs, rows] & ((1 << 28) - 1),) + tuple(
        (table[qs, rows] >> bit) & 1 == 1 for bit in (28, 29, 30))
    for variant in (with_planes, words_only):
        got = jax.jit(jax.vmap(step, (None, 0, 0, None)))(variant, qs, labels[rows], False)
        by_symbol = jax.jit(jax.vmap(step, (None, 0, None, None, 0)))(
            variant, qs, labels[0], False, rows.astype(np.int32))  # the label is not read
        for g, s, w in zip(got, by_symbol, want, strict=True):
            np.testing.assert_array_equal(np.asarray(g), w)
            np.testing.assert_array_equal(np.asarray(s), w)
        q, *_ = step(variant, num_states - 1, labels[1], False)
        assert int(q) == table[num_states - 1, 1] & ((1 << 28) - 1)


def test_labels_wider_than_an_int32_code():
    """33 propositions: no code table, too wide for integer codes; the empty label, a single
    proposition and one past bit 31 each read their own symbol."""
    props = tuple(f"p{i}" for i in range(33))
    spec = compile_spec("!p32 U p1", props, zero_or_one(33))
    assert spec.symbol_of_code.shape == (0,)
    labels = np.zeros((3, 33), bool)
    labels[1, 1] = labels[2, 32] = True
    q, _, success, violation = jax.vmap(step, (None, None, 0, None))(spec, spec.init, labels, False)
    assert not bool(success[0]) and not bool(violation[0]) and int(q[0]) == int(spec.init)
    assert bool(success[1]) and bool(violation[2])


def _numpy_step(spec, q, label, slot):
    """The step of one unstacked spec from its own tables; a state past them is padding."""
    delta, epsilon = np.asarray(spec.delta), np.asarray(spec.epsilon)
    if q >= delta.shape[0]:
        return q, False, False, False
    if slot >= 0:
        target = epsilon[q, slot] if slot < epsilon.shape[1] else -1
        nxt, acc = (int(target) if target >= 0 else q), False
    else:
        rows = np.nonzero((np.asarray(spec.alphabet) == label).all(axis=1))[0]
        nxt = int(delta[q, rows[0]]) if len(rows) else q
        acc = bool(len(rows)) and bool(np.asarray(spec.accepting)[q, rows[0]])
    return nxt, acc, bool(np.asarray(spec.success)[nxt]), bool(np.asarray(spec.violation)[nxt])


@pytest.mark.parametrize("num_props", [4, 13])  # a code table (P <= 12) or none
def test_step_in_batch_with_epsilon_slots_and_unknown_labels(num_props):
    """Integer epsilon slots (none, each slot, slots only padding has, past the end), labels in
    and out of the alphabet, padded states: `step_in_batch` on a stack agrees with numpy on
    each member's own tables."""
    props = PROPS + tuple(f"x{i}" for i in range(num_props - 4))
    formulas = ["FG a | GF b", "FG a & F(b & F c)", "!a U (b & F c)", "GF a & GF b & G !d"]
    specs = [compile_spec(f, props, zero_or_one(num_props)) for f in formulas]
    batch = stack(specs)
    num_slots = batch.epsilon.shape[-1]
    assert num_slots == 2 and {s.epsilon.shape[-1] for s in specs} == {1, 2}
    rng = np.random.default_rng(num_props)
    n = 3000
    ids = rng.integers(0, len(specs), n)
    qs = rng.integers(0, batch.delta.shape[1], n)
    alphabet = np.asarray(batch.alphabet[0])
    labels = alphabet[rng.integers(0, len(alphabet), n)]
    unknown = rng.random(n) < 0.3  # random labels: mostly several propositions at once
    labels[unknown] = rng.random((int(unknown.sum()), num_props)) < 0.3
    slots = rng.integers(-2, num_slots + 2, n).astype(np.int32)
    got = jax.jit(jax.vmap(step_in_batch, (None, 0, 0, 0, 0)))(batch, ids, qs, labels, slots)
    got = list(zip(*[np.asarray(x).tolist() for x in got]))
    want = [_numpy_step(specs[i], q, label, slot)
            for i, q, label, slot in zip(ids, qs.tolist(), labels, slots.tolist())]
    assert got == want
    # the same steps from the env-reported symbol: the label's row, or for an unknown label
    # any value outside the alphabet (both ends)
    rows = (labels[:, None, :] == alphabet[None]).all(-1)
    symbols = np.where(rows.any(-1), rows.argmax(-1), rng.choice([-1, len(alphabet), 99], n))
    by_symbol = jax.jit(jax.vmap(step_in_batch, (None, 0, 0, 0, 0, 0)))(
        batch, ids, qs, labels, slots, symbols.astype(np.int32))
    assert list(zip(*[np.asarray(x).tolist() for x in by_symbol])) == want
    moved, accepted = np.array([w[0] for w in want]) != qs, np.array([w[1] for w in want])
    assert min((moved & (slots >= 0)).sum(), (moved & (slots < 0)).sum(), accepted.sum()) > 20
