"""DeepLTL's candidate search: the memoised search equals a plain transcription of the
reference's depth-first search, is complete on the paper's Letter specs, and the compact pair
table round-trips through stacking and the cache."""

import warnings

import numpy as np
import pytest
from automata_paper import paper_groups

from specrl_jax.automata import cache, compile_spec, pairs, stack, translate, zero_or_one
from specrl_jax.automata import subgoals as sg
from specrl_jax.automata.tensors import DEFAULT_MAX_LENGTH, DEFAULT_MAX_SEQUENCES

LETTERS = tuple("abcdefghijkl")


def _reference_dfs(out, q, path, index, acc_t):
    """The reference's search, literally: every simple path, pairwise pruning at each level."""
    index[q] = len(path)
    neg, paths = 0, []
    for t in out[q]:
        if t.dead:
            neg |= t.symbols
            continue
        path.append(t)
        tracked = t if t.accepting else acc_t
        if t.target in index:
            if tracked is not None and tracked in path[index[t.target]:]:
                futures = [((), index[t.target])]
            else:
                path.pop()
                if t.source != t.target:
                    neg |= t.symbols
                continue
        else:
            futures = _reference_dfs(out, t.target, path, index, tracked)
            if not futures:
                neg |= t.symbols
        paths += [(((t, 0),) + steps, loop) for steps, loop in futures]
        path.pop()
    del index[q]
    removed = set()
    for i in range(len(paths)):
        for j in range(i + 1, len(paths)):
            if i in removed or j in removed:
                continue
            ri = tuple(t.symbols for t, _ in paths[i][0])
            rj = tuple(t.symbols for t, _ in paths[j][0])
            if len(ri) < len(rj) and sg._contained(rj, ri):
                removed.add(j)
            elif len(ri) > len(rj) and sg._contained(ri, rj):
                removed.add(i)
                break
    return [(((steps[0][0], neg),) + steps[1:], loop)
            for k, (steps, loop) in enumerate(paths) if k not in removed]


def _as_sequences(steps_and_loops, num_loops):
    out = []
    for steps, loop in steps_and_loops:
        seq = [(t.symbols, avoid, t.slot) for t, avoid in steps]
        out.append(seq[:loop] + seq[loop:] * num_loops)
    return out


ZONES = ("blue", "green", "magenta", "yellow")


@pytest.mark.parametrize("formula, props", [
    ("GF blue & GF green & G (blue -> F yellow)", ZONES),
    ("FG blue & F (yellow & F green)", ZONES),
    ("!blue U (green & (!yellow U (magenta & (!blue U yellow))))", ZONES),
    ("GF (magenta & (!blue U green)) & G !yellow", ZONES),
    ("(F blue) & (!blue U (green & F yellow))", ZONES),
    # a paper `rsp` spec: 27 states, one SCC of 21 (the budgeted search was incomplete here)
    ("(G F a) & G(a -> (F(b & F c) & (!d U e))) & G !(f | g | h | i)", LETTERS),
])
def test_memoised_search_equals_the_reference_dfs(formula, props):
    aut = translate.translate(formula, props, zero_or_one(len(props)))
    num_loops = 0 if aut.is_finite else sg.NUM_LOOPS_INFINITE
    search = sg._Search(aut)
    out = [sg._transitions(aut, q) for q in range(aut.num_states)]
    for q in range(aut.num_states):
        if aut.violation[q]:
            continue
        expected = _as_sequences(_reference_dfs(out, q, [], {}, None), num_loops)
        got = [[(t.symbols, avoid, t.slot) for t, avoid in sg._to_sequence(p, num_loops)]
               for p in search.paths(q)]
        assert got == expected, (formula, q)


def test_letter_paper_specs_are_complete_and_small():
    formulas, props, alphabet = paper_groups()["letter"]
    for text in formulas:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no search fallback, nothing dropped
            spec = compile_spec(text, props, alphabet, use_cache=False)
        assert spec.nbytes < 64 * 1024, text
        assert spec.seq_pair.dtype == np.int16 and int(spec.seq_pair.max()) < len(spec.pair_reach)


def test_pairs_stack_and_padding():
    a = compile_spec("FG blue & F (yellow & F green)", ZONES, zero_or_one(4))
    b = compile_spec("F blue", ZONES, zero_or_one(4))
    stacked = stack([a, b])
    for i, spec in enumerate((a, b)):
        mine = pairs(spec, np.asarray(spec.seq_pair))
        member = pairs(jax_take(stacked, i), np.asarray(stacked.seq_pair)[i])
        s, c, length = np.asarray(spec.seq_pair).shape
        for got, want in zip(member, mine):
            got = np.asarray(got)
            assert np.array_equal(got[:s, :c, :length], np.asarray(want))
            assert not got[s:].any() if got.dtype == bool else (got[s:] == -1).all()
    padding = pairs(b, np.zeros((), np.int16))
    assert not padding.reach.any() and not padding.avoid.any() and int(padding.epsilon_slot) == -1


def jax_take(stacked, i):
    return type(stacked)(**{k: np.asarray(v)[i] for k, v in stacked.__dict__.items()})


def test_old_format_cache_entry_is_rebuilt(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    key = cache.cache_key("F a", ("a", "b"), zero_or_one(2),
                          max_sequences=DEFAULT_MAX_SEQUENCES, max_length=DEFAULT_MAX_LENGTH)
    fresh = compile_spec("F a", ("a", "b"), zero_or_one(2), use_cache=False)
    old = {k: np.asarray(v) for k, v in fresh.__dict__.items() if not k.startswith(("pair", "seq"))}
    old["seq_reach"] = np.zeros((3, 1, 1, 3), bool)  # the bool[S, C, L, A] layout of format 1
    cache.save(key, old)
    spec = compile_spec("F a", ("a", "b"), zero_or_one(2))
    assert np.array_equal(spec.seq_pair, fresh.seq_pair)
    assert "seq_pair" in cache.load(key)


def test_long_grid_cell_compiles_through_the_shortest_path_search():
    formula = "!a U (b & (!c U (d & (!e U (f & (!g U (h & (!i U (j & (!k U l))))))))))"
    with pytest.warns(UserWarning, match="shortest paths"):
        spec = compile_spec(formula, LETTERS, zero_or_one(12), use_cache=False)
    q = int(spec.init)
    (c,) = np.nonzero(np.asarray(spec.seq_valid[q]))[0]
    steps = pairs(spec, np.asarray(spec.seq_pair[q, c]))
    reach = [LETTERS[int(np.argmax(r)) - 1] for r in np.asarray(steps.reach)[: spec.seq_length[q, c]]]
    assert reach == list("bdfhjl")
