"""compile_spec at the Python boundary: errors that point at the problem, shapes, cache."""

import numpy as np
import pytest

from specrl_jax.automata import all_subsets, cache, compile_spec, translate, zero_or_one
from specrl_jax.automata.tensors import DEFAULT_MAX_LENGTH, DEFAULT_MAX_SEQUENCES

PROPS = ("a", "b", "c", "d")


def test_syntax_error_names_the_formula():
    with pytest.raises(ValueError, match=r"cannot parse LTL formula 'a & \(b'"):
        compile_spec("a & (b", PROPS, zero_or_one(4))


def test_unknown_proposition_is_named():
    with pytest.raises(ValueError, match=r"\['zz'\].*known: \['a', 'b', 'c', 'd'\]"):
        compile_spec("F zz & F a", PROPS, zero_or_one(4))


def test_alphabet_shape_and_rows_are_checked():
    with pytest.raises(ValueError, match=r"shape \[A, 4\]"):
        compile_spec("F a", PROPS, zero_or_one(3))
    with pytest.raises(ValueError, match="distinct"):
        compile_spec("F a", PROPS, np.vstack([zero_or_one(4), zero_or_one(4)[:1]]))
    with pytest.raises(ValueError, match="pass the env's alphabet"):
        compile_spec("F p0", tuple(f"p{i}" for i in range(12)))
    with pytest.raises(TypeError, match="must be a str"):
        compile_spec(3, PROPS, zero_or_one(4))


def test_satisfiability_is_relative_to_the_alphabet():
    with pytest.raises(ValueError, match="unsatisfiable over the alphabet"):
        compile_spec("F(a & b)", PROPS, zero_or_one(4))
    spec = compile_spec("F(a & b)", PROPS, all_subsets(4))
    assert bool(spec.is_finite)


def test_owl_implication_syntax_is_accepted():
    a = compile_spec("((a | b) => F c) U d", PROPS, zero_or_one(4))
    b = compile_spec("((a | b) -> F c) U d", PROPS, zero_or_one(4))
    assert np.array_equal(a.delta, b.delta) and np.array_equal(a.success, b.success)


def test_letter_tables_are_over_the_declared_alphabet():
    spec = compile_spec("!(a | b) U (c & F d)", tuple("abcdefghijkl"), zero_or_one(12))
    assert spec.delta.shape[1] == 13 and spec.pair_reach.shape[-1] == 13
    assert spec.delta.dtype == np.int32 and spec.accepting.dtype == bool
    assert bool(spec.is_finite) and int(spec.init) == 0
    # one dead sink and one success sink, both absorbing
    for flag in (spec.violation, spec.success):
        (q,) = np.nonzero(np.asarray(flag))[0]
        assert (np.asarray(spec.delta)[q] == q).all()


def test_second_compile_reads_the_disk_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    first = compile_spec("GF a & GF b & G !c", PROPS, zero_or_one(4))
    assert len(list((tmp_path / "automata").glob("*.npz"))) == 1

    def fail(*_):
        raise AssertionError("translated again despite the cache")

    monkeypatch.setattr(translate, "translate", fail)
    second = compile_spec("GF a & GF b & G !c", PROPS, zero_or_one(4))
    for x, y in zip(first.__dict__.values(), second.__dict__.values()):
        assert np.array_equal(x, y)
    with pytest.raises(AssertionError, match="translated again"):
        compile_spec("GF a & GF b & G !c", PROPS, all_subsets(4))  # other alphabet, other key


def test_unreadable_cache_entry_is_rebuilt(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECRL_JAX_CACHE_DIR", str(tmp_path))
    key = cache.cache_key("F a", PROPS, zero_or_one(4), max_sequences=DEFAULT_MAX_SEQUENCES,
                          max_length=DEFAULT_MAX_LENGTH)
    (tmp_path / "automata").mkdir()
    (tmp_path / "automata" / f"{key}.npz").write_bytes(b"not a zip file")
    spec = compile_spec("F a", PROPS, zero_or_one(4))
    assert bool(spec.is_finite)
    assert cache.load(key) is not None
