"""`where_needed`: the per-item choice between an expensive function and a default, under no,
one and two `vmap`s, on its gathered and its whole-batch paths."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax.envs.compaction import where_needed


def expensive(x):
    return {"y": jnp.sin(x["a"]) * x["scale"], "z": jnp.sum(x["a"])}


def needs(x):
    return x["a"][0] > 0.7


def default(x):
    return {"y": x["a"] + x["scale"], "z": jnp.float32(-1.0)}


def reference(x):
    pick = lambda e, d: jnp.where(needs(x), e, d)
    return jax.tree.map(pick, expensive(x), default(x))


def _assert_same(a, b):
    for name in ("y", "z"):
        np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]))


@pytest.mark.parametrize("capacities", [(0.2, 0.5), (0.1,)])
def test_two_vmaps_merge_into_one_batch(capacities):
    """3 x 20 items, 18 needing: with sub-batches of 12 and 30 the expensive function runs on a
    gathered 30 of the 60, with only 6 (too few) on 6 at a time, never on all 60; the results
    are the reference's."""
    a = jax.random.uniform(jax.random.key(0), (3, 20, 4))
    inner = {"a": 0, "scale": None}
    for scale in (jnp.float32(2.0), jnp.arange(3.0)):  # unbatched, or batched by the outer vmap
        x = {"a": a, "scale": scale}
        outer = {"a": 0, "scale": None if scale.ndim == 0 else 0}
        function = jax.vmap(jax.vmap(where_needed(expensive, needs, default, capacities),
                                     in_axes=(inner,)), in_axes=(outer,))
        _assert_same(jax.jit(function)(x),
                     jax.vmap(jax.vmap(reference, in_axes=(inner,)), in_axes=(outer,))(x))
        assert int(jnp.sum(a[..., 0] > 0.7)) == 18
        program = str(jax.make_jaxpr(function)(x))
        assert ("f32[30,4] = sin" in program) == (0.5 in capacities)  # a gathered 30 of 60
        assert ("f32[6,4] = sin" in program) == (0.1 in capacities)  # 6 at a time, in a loop
        assert "f32[60,4] = sin" not in program


def test_the_expensive_function_is_traced_once_for_every_size_and_level():
    """Its Python runs once per item shape: each sub-batch size and each merged `vmap` level
    batches that one trace (an arm's contact solve takes tens of seconds to trace)."""
    calls = []

    def counted(x):
        calls.append(1)
        return expensive(x)

    function = where_needed(counted, needs, default, (0.1, 0.2, 0.5))
    x = {"a": jax.random.uniform(jax.random.key(1), (3, 20, 4)), "scale": jnp.float32(2.0)}
    batched = jax.vmap(jax.vmap(function, in_axes=({"a": 0, "scale": None},)),
                       in_axes=({"a": 0, "scale": None},))
    inner = {"a": 0, "scale": None}
    _assert_same(jax.jit(batched)(x), jax.vmap(jax.vmap(reference, in_axes=(inner,)),
                                               in_axes=(inner,))(x))
    assert len(calls) == 1


def test_one_item_and_a_loop_inside_vmap():
    function = where_needed(expensive, needs, default, [0.5])
    for value in (0.9, 0.2):
        x = {"a": jnp.array([value, 0.3]), "scale": jnp.float32(3.0)}
        _assert_same(function(x), reference(x))

    def loop(function, x):
        body = lambda _, c: {"a": 0.5 * c["a"] + function(c)["y"], "scale": c["scale"]}
        return jax.lax.fori_loop(0, 4, body, x)["a"]

    x = {"a": jax.random.uniform(jax.random.key(1), (16, 2)), "scale": jnp.ones(16)}
    got = jax.jit(jax.vmap(lambda x: loop(function, x)))(x)
    np.testing.assert_allclose(got, jax.vmap(lambda x: loop(reference, x))(x), rtol=1e-6)


def test_runs_counted_by_how_many_items_need_it():
    """With no item needing it the expensive function does not run (counted by a callback
    inside it); with one item it runs once, on the gathered sub-batch of 2; with 5 items, three
    times (2 + 2 + 1)."""
    calls = []

    def counted(x):
        jax.debug.callback(lambda: calls.append(1))
        return expensive(x)

    function = jax.jit(jax.vmap(where_needed(counted, needs, default, (0.25,))))
    for needing, runs in ((0, 0), (1, 1), (5, 3)):
        calls.clear()
        x = {"a": jnp.full((8, 2), 0.1).at[:needing, 0].set(0.9), "scale": jnp.ones(8)}
        _assert_same(jax.block_until_ready(function(x)), jax.vmap(reference)(x))
        assert len(calls) == runs


def test_where_needed_inside_where_needed():
    """An inner choice inside the outer expensive function (the arm's overflow solve inside its
    gated solve) gives the nested reference under two vmaps."""
    inner_needs = lambda x: x["a"][1] > 0.5
    inner = where_needed(expensive, inner_needs, default, (0.25,))
    outer = where_needed(inner, needs, lambda x: {"y": -x["a"], "z": jnp.float32(0.0)}, (0.5,))

    def nested_reference(x):
        pick = lambda c, e, d: jnp.where(c, e, d)
        inside = jax.tree.map(lambda e, d: pick(inner_needs(x), e, d), expensive(x), default(x))
        return jax.tree.map(lambda e, d: pick(needs(x), e, d), inside,
                            {"y": -x["a"], "z": jnp.float32(0.0)})

    x = {"a": jax.random.uniform(jax.random.key(2), (2, 16, 2)), "scale": jnp.float32(2.0)}
    axes = ({"a": 0, "scale": None},)
    got = jax.jit(jax.vmap(jax.vmap(outer, in_axes=axes), in_axes=axes))(x)
    _assert_same(got, jax.vmap(jax.vmap(nested_reference, in_axes=axes), in_axes=axes)(x))


def test_needs_must_give_one_bool_per_item():
    function = where_needed(expensive, lambda x: x["a"][:1] > 0.7, default, [0.5])
    x = {"a": jnp.ones((8, 2)), "scale": jnp.ones(8)}
    with pytest.raises(ValueError, match="one bool per item"):
        jax.vmap(function)(x)


def test_capacities_must_be_fractions():
    for bad in ([], [0.5, 0.0], [1.5]):
        with pytest.raises(ValueError, match=r"\(0, 1\]"):
            where_needed(expensive, needs, default, bad)
