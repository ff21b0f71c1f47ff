"""Traced programs on disk (baselines/programs.py) and the key a training names them by
(`experiment.program_key`): a program read back computes what the traced one does, another key,
static argument or argument shape is another entry while static metadata named by its address
is not, a program `jax.export` refuses compiles as before and is not exported again, a damaged
entry is traced again, nothing is stored with caching off, and the key changes with every input
of the programs."""

import dataclasses
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from specrl_jax import cache
from specrl_jax.baselines import programs, runs
from specrl_jax.baselines.ppo import env_mesh
from specrl_jax.benchmark import experiment
from specrl_jax.tasks.sources import ByContent


@struct.dataclass
class Carry:
    x: jax.Array  # float32[N]
    key: jax.Array  # a typed key


def step(carry: Carry, n: int, scale: jax.Array) -> tuple[Carry, dict[str, jax.Array]]:
    """`n` (static) scalings of the carry plus noise, and a metric."""
    key, key_noise = jax.random.split(carry.key)
    x = carry.x * scale**n + jax.random.normal(key_noise, carry.x.shape)
    return Carry(x, key), {"total": jnp.sum(x)}


def _carry(size: int = 3) -> Carry:
    return Carry(jnp.arange(float(size)), jax.random.key(0))


def _host(tree):
    """The tree's arrays on the host, typed keys as their data."""
    return [np.asarray(jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key)
                       else x) for x in jax.tree.leaves(tree)]


def _compile(key: str = "k", carry: Carry | None = None, n: int = 2):
    return programs.compile_cached(step, (carry or _carry(), n, jnp.float32(1.5)), key,
                                   static_argnums=1, donate_argnums=0)


def _entries(tmp_path) -> list[str]:
    return sorted(p.name for p in (tmp_path / "programs").glob("*.npz"))


def test_a_stored_program_computes_what_the_traced_one_does(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    want = jax.jit(step, static_argnums=1)(_carry(), 2, jnp.float32(1.5))
    (traced, read_first), (stored, read_again) = _compile(), _compile()
    assert (read_first, read_again) == (False, True) and len(_entries(tmp_path)) == 1
    for compiled in (traced, stored):
        got = compiled(_carry(), jnp.float32(1.5))  # the carry is donated: a fresh one each
        assert jax.tree.structure(got) == jax.tree.structure(want)
        for a, b in zip(_host(got), _host(want)):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(TypeError, match="expected arguments of structure"):
        stored({"x": jnp.ones(3)}, jnp.float32(1.5))
    # another key, static argument or argument shape: another program
    for options in ({"key": "other"}, {"n": 3}, {"carry": _carry(4)}):
        assert _compile(**options)[1] is False
    assert len(_entries(tmp_path)) == 4


def test_shapes_arrays_and_a_mesh_of_one_device_name_the_same_entry(tmp_path, monkeypatch):
    """A fresh training compiles its step from shapes while a resumed one has arrays (placed
    by a one-device mesh): the resumed run reads the fresh run's entry."""
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), _carry())
    mesh = env_mesh([jax.devices()[0]])
    placed = jax.device_put(_carry(), jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec()))
    assert [_compile(carry=c)[1] for c in (shapes, _carry(), placed)] == [False, True, True]
    assert len(_entries(tmp_path)) == 1


class Tag:
    """Static metadata of a default repr (naming its address), equal only to itself."""


@struct.dataclass
class Tagged:
    x: jax.Array  # float32[N]
    tag: Tag = struct.field(pytree_node=False)


def test_static_metadata_of_a_default_repr_names_the_same_entry_in_every_run(
        tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    read = []
    for _ in range(2):  # each time a new instance, as in a new process
        compiled, was_read = programs.compile_cached(lambda t: t.replace(x=t.x * 2),
                                                     (Tagged(jnp.ones(2), Tag()),), "k")
        read.append(was_read)
        np.testing.assert_array_equal(compiled(Tagged(jnp.ones(2), Tag())).x, [2.0, 2.0])
    assert read == [False, True]


def test_static_metadata_compared_by_content_names_its_content(tmp_path, monkeypatch):
    # a bank carried as static metadata is compiled into the program: other contents, another
    # entry (not the program of the first bank)
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))

    def scaled(t):
        return t.replace(x=t.x * jnp.asarray(t.tag.tree))

    for bank, read_before in ((np.ones(2), False), (np.full(2, 10.0), False), (np.ones(2), True)):
        tagged = Tagged(jnp.ones(2), ByContent(bank))
        compiled, read = programs.compile_cached(scaled, (tagged,), "k")
        assert read is read_before
        np.testing.assert_array_equal(compiled(tagged).x, bank)


def test_a_program_export_refuses_compiles_as_before_and_is_not_exported_again(
        tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    heard = []

    def logged(x):
        jax.debug.callback(heard.append, x)  # a host callback: `jax.export` refuses it
        return x + 1

    exports = []
    export = jax.export.export
    monkeypatch.setattr(jax.export, "export", lambda *a, **k: exports.append(a) or export(*a, **k))
    for _ in range(2):
        compiled, read = programs.compile_cached(logged, (jnp.ones(2),), "k")
        assert not read
        np.testing.assert_array_equal(compiled(jnp.ones(2)), [2.0, 2.0])
    jax.effects_barrier()
    assert len(exports) == 1 and len(heard) == 2 and len(_entries(tmp_path)) == 1


def test_a_damaged_entry_is_traced_again(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    _compile()
    (name,) = _entries(tmp_path)
    cache.save_arrays(str(tmp_path / "programs"), name[: -len(".npz")],
                      {"exported": np.arange(7, dtype=np.uint8),
                       "out_structure": np.zeros(3, np.uint8)})
    compiled, read = _compile()
    assert not read and _compile()[1]  # traced again, stored again
    want = jax.jit(step, static_argnums=1)(_carry(), 2, jnp.float32(1.5))
    for a, b in zip(_host(compiled(_carry(), jnp.float32(1.5))), _host(want)):
        np.testing.assert_array_equal(a, b)


def test_nothing_is_stored_with_caching_off(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, "off")
    monkeypatch.chdir(tmp_path)
    assert [_compile()[1] for _ in range(2)] == [False, False]
    assert not list(tmp_path.rglob("*.npz"))


def test_the_program_key_changes_with_every_input_of_the_programs(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    world, params, method, config = experiment.build(
        "ltl2action", "LetterLTL0-v0", {"num_envs": 4, "num_steps": 8}, None, jax.random.key(0))
    mesh = env_mesh()

    def key(config=config, params=params, method=method, name="ltl2action", options=None):
        settings = runs.run_config(config, 1, {"method": name, "env": "LetterLTL0-v0"})
        return experiment.program_key(name, settings, world, params, method, mesh, options)

    base = key()
    assert base == key() and len(base) == 64
    encoder = tmp_path / "encoder.msgpack"
    encoder.write_bytes(b"one")
    with_file = key(options={"encoder": str(encoder)})
    encoder.write_bytes(b"two")  # the same path, other contents
    changed = [
        key(config=dataclasses.replace(config, lr=1e-3)),  # a setting
        key(params=jax.tree.map(lambda x: x + 1, params)),  # the world's data (the map bank)
        key(method=dataclasses.replace(method, encoder={"w": jnp.ones(2)})),  # a method's arrays
        with_file, key(options={"encoder": str(encoder)}),  # a file an option names
    ]
    assert len({base, *changed}) == 1 + len(changed)
    # an option that is an object, not plain data (its text need not name its content)
    assert key(options={"network": object()}) is None
    # a mesh on another device than the default one: a stored program would run on the default
    other = types.SimpleNamespace(size=1, devices=np.array([object()]))
    assert experiment.program_key("ltl2action", runs.run_config(config, 1, {}), world, params,
                                  method, other, None) is None
    with jax.default_device(jax.devices()[0].platform):  # the default named by its platform
        assert key() is not None
    monkeypatch.setattr(cache, "package_digest", lambda: "another package")
    assert key() != base
    # a method defined outside the package, or with a hook from outside: traced every time
    own = experiment.get_method("ltl2action")
    for foreign in (dataclasses.replace(own, make_method=lambda *args, **options: None),
                    dataclasses.replace(own, prepare_training=lambda *args: args[0])):
        monkeypatch.setattr(experiment, "get_method", lambda name, spec=foreign: spec)
        assert key() is None
    monkeypatch.setenv(cache.ENV_VAR, "off")
    assert key() is None
