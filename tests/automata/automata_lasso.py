"""Checking compiled specs on ultimately periodic words u v^w against Spot.

Our side runs `step` inside one jitted, vmapped scan over (spec, word, epsilon timing) entries;
Spot's side intersects its own automaton of the formula with the word's automaton.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import spot

from specrl_jax.automata import compile_spec, stack, step

MAX_U, MAX_V, PREFIXES = 3, 3, 4


def letter(row, aps, props) -> str:
    lits = [p if row[props.index(p)] else f"!{p}" for p in aps]
    return " & ".join(lits) if lits else "1"


def allowed(alphabet, aps, props) -> str:
    return " | ".join(sorted({f"({letter(r, aps, props)})" for r in alphabet}))


def random_words(rng, num_symbols, count):
    return [(rng.integers(num_symbols, size=rng.integers(0, MAX_U + 1)).tolist(),
             rng.integers(num_symbols, size=rng.integers(1, MAX_V + 1)).tolist())
            for _ in range(count)]


@functools.partial(jax.jit, static_argnames=("length",))
def _run(batch, spec_ids, syms, jump_t, jump_slot, window, length):
    def one(spec_id, seq, jt, js, win):
        spec = jax.tree.map(lambda x: x[spec_id], batch)

        def body(q, inp):
            i, sym = inp
            props = spec.alphabet[sym]
            q_jump = step(spec, q, props, js)[0]
            q = jnp.where(i == jt, q_jump, q)
            q, acc, succ, viol = step(spec, q, props, False)
            return q, (acc & (i >= win[0]) & (i < win[1]), succ, viol)

        _, (acc, succ, viol) = jax.lax.scan(body, spec.init, (jnp.arange(length), seq))
        return acc.any(), succ[:PREFIXES], viol[:PREFIXES]

    return jax.vmap(one)(spec_ids, syms, jump_t, jump_slot, window)


def check_formulas(formulas, props, alphabet, rng, words_per_formula=6):
    """Compile every formula and compare with Spot; returns (number compiled, number unsat).

    For each random lasso: acceptance (some epsilon timing accepts iff Spot accepts), and the
    success / violation flags after each prefix (no epsilon taken) against "every / no
    continuation over the alphabet satisfies", decided by Spot.
    """
    props = list(props)
    specs, refs = [], []
    unsat = 0
    for text in formulas:
        f = spot.formula(text)
        aps = sorted(str(a) for a in spot.atomic_prop_collect(f))
        pos, neg = spot.translate(f), spot.translate(spot.formula.Not(f))
        universe = spot.parse_word(f"cycle{{{allowed(alphabet, aps, props)}}}", pos.get_dict())
        if not pos.intersects(universe.as_automaton()):
            try:
                compile_spec(text, props, alphabet)
            except ValueError as err:
                assert "unsatisfiable" in str(err), text
                unsat += 1
                continue
            raise AssertionError(f"{text!r} is unsatisfiable over the alphabet but compiled")
        specs.append(compile_spec(text, props, alphabet))
        refs.append((text, aps, pos, neg))
    if not specs:
        return 0, unsat
    batch = stack(specs)
    num_states = batch.delta.shape[1]
    length = MAX_U + 4 * num_states * MAX_V
    entries, expect = [], []
    for k, (text, aps, pos, neg) in enumerate(refs):
        has_eps = bool((np.asarray(specs[k].epsilon) >= 0).any())
        num_slots = specs[k].epsilon.shape[-1]
        for u, v in random_words(rng, len(alphabet), words_per_formula):
            word = u + v * ((length - len(u)) // len(v) + 1)
            body = "; ".join(letter(alphabet[s], aps, props) for s in u)
            cyc = "; ".join(letter(alphabet[s], aps, props) for s in v)
            w = spot.parse_word(f"{body}{'; ' if u else ''}cycle{{{cyc}}}", pos.get_dict())
            accepted = pos.intersects(w.as_automaton())
            flags = []
            for n in range(1, PREFIXES + 1):
                pre = "; ".join(letter(alphabet[s], aps, props) for s in word[:n])
                cont = spot.parse_word(f"{pre}; cycle{{{allowed(alphabet, aps, props)}}}",
                                       pos.get_dict()).as_automaton()
                flags.append((not neg.intersects(cont), not pos.intersects(cont)))
            window = (len(u) + 3 * num_states * len(v), len(u) + 4 * num_states * len(v))
            jumps = [(-1, -1)]
            if has_eps:
                jumps += [(t, e) for t in range(len(u) + 2 * num_states * len(v))
                          for e in range(num_slots)]
            first = len(entries)
            for t, e in jumps:
                entries.append((k, word[:length], t, e, window))
            expect.append((text, u, v, accepted, flags, first, len(entries)))
    ids, syms, jt, js, win = map(np.asarray, zip(*entries))
    acc, succ, viol = jax.device_get(_run(batch, ids, syms, jt, js, win, length))
    for text, u, v, accepted, flags, lo, hi in expect:
        assert acc[lo:hi].any() == accepted, f"{text!r} on {u} ({v})^w: Spot says {accepted}"
        got = list(zip(succ[lo].tolist(), viol[lo].tolist()))
        assert got == flags, f"{text!r}: (success, violation) after prefixes {got} != {flags}"
    return len(specs), unsat
