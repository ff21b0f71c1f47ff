"""Zone physics backends (`ZoneConfig.physics`) and the opt-in layout bank (`with_map_bank`).

The Warp tests run only where warp-lang is importable (MuJoCo Warp through MJX, on a CUDA GPU or
on a CPU where warp-lang has its CPU compiler); the default backend is checked against MuJoCo C
in test_zone_physics.py.
"""

from __future__ import annotations

import types
import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from envs.ant_states import settled_ant

import specrl_jax
from specrl_jax.envs.zone import ZoneConfig
from specrl_jax.envs.zone import physics as zone_physics
from specrl_jax.envs.zone.layout import from_bank
from specrl_jax.envs.zone.physics import Physics, resolve_physics, warp_available

D4 = [
    lambda x, y: (x, y),
    lambda x, y: (-y, x),
    lambda x, y: (-x, -y),
    lambda x, y: (y, -x),
    lambda x, y: (-x, y),
    lambda x, y: (-y, -x),
    lambda x, y: (x, -y),
    lambda x, y: (y, x),
]


def test_unknown_or_missing_backend_is_rejected():
    with pytest.raises(ValueError, match="unknown physics backend 'bullet'"):
        ZoneConfig(physics="bullet")
    if not warp_available():
        with pytest.raises(ValueError, match="warp-lang"):
            specrl_jax.make("PointLTL0-v0", physics="warp")


def test_auto_physics_is_warp_for_car_and_ant_on_one_cuda_gpu_only(monkeypatch):
    assert ZoneConfig().physics == "auto"
    on_this_machine = "warp" if zone_physics._one_cuda_gpu() else "jax"
    assert specrl_jax.make("CarLTL0-v0")[0].physics.backend == on_this_machine
    monkeypatch.setattr(zone_physics, "_one_cuda_gpu", lambda: True)
    assert [resolve_physics("auto", r) for r in ("Point", "Car", "Ant")] == ["jax", "warp", "warp"]
    assert resolve_physics("jax", "Ant") == "jax"
    monkeypatch.setattr(zone_physics, "_one_cuda_gpu", lambda: False)
    assert [resolve_physics("auto", r) for r in ("Point", "Car", "Ant")] == ["jax"] * 3
    assert resolve_physics("warp", "Point") == "warp"
    with pytest.raises(ValueError, match=r"accepted: \('auto', 'jax', 'warp'\)"):
        resolve_physics("mjx", "Car")


def test_auto_physics_without_warp_lang_on_a_gpu_warns_and_steps_with_jax(monkeypatch):
    monkeypatch.setattr(zone_physics, "_one_cuda_gpu", lambda: True)
    monkeypatch.setattr(zone_physics, "warp_available", lambda: False)
    with pytest.warns(UserWarning, match=r"the Ant steps with MJX's JAX .*specrl-jax\[cuda\]"):
        assert resolve_physics("auto", "Ant") == "jax"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert resolve_physics("auto", "Point") == "jax"  # MJX-JAX is its default anyway


def test_one_cuda_gpu_needs_one_gpu_device_in_float32(monkeypatch):
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(jax, "device_count", lambda: 2)
    assert not zone_physics._one_cuda_gpu()  # several devices: MJX-JAX, which XLA can split
    monkeypatch.setattr(jax, "device_count", lambda: 1)
    monkeypatch.setattr(jax, "devices", lambda: [types.SimpleNamespace(device_kind="NVIDIA H200")])
    assert zone_physics._one_cuda_gpu()
    with jax.enable_x64(True):
        assert not zone_physics._one_cuda_gpu()  # MuJoCo Warp is float32 only
    monkeypatch.setattr(jax, "devices", lambda: [types.SimpleNamespace(device_kind="AMD MI300X")])
    assert not zone_physics._one_cuda_gpu()
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert not zone_physics._one_cuda_gpu()


# ---- layout bank ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def banked():
    env, params = specrl_jax.make("PointLTL1-v0")
    params = env.with_map_bank(jax.random.key(0), params, num_maps=24)
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    return env, params, reset


def test_bank_rejects_bad_sizes():
    env, params = specrl_jax.make("PointLTL0-v0")
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="num_maps must be a positive int"):
            env.with_map_bank(jax.random.key(0), params, num_maps=bad)


def test_bank_layouts_are_exact_layouts(banked):
    _, params, _ = banked
    xy = np.asarray(params.map_bank)
    assert xy.shape == (24, 9, 2) and xy.dtype == np.float32
    agent, zones = xy[:, 0], xy[:, 1:]
    pair = np.linalg.norm(zones[:, :, None] - zones[:, None, :], axis=-1)
    pair[:, np.arange(8), np.arange(8)] = np.inf
    assert pair.min() >= 2 * 0.65 - 1e-5  # level-1 keepouts
    assert np.linalg.norm(zones - agent[:, None], axis=-1).min() >= 0.4 + 0.65 - 1e-5
    assert np.abs(zones).max() <= 2.5 - 0.65 + 1e-6
    assert len(np.unique(agent.round(6), axis=0)) == 24


def test_bank_resets_use_symmetric_images_with_fresh_pose_and_motion(banked):
    env, params, reset = banked
    _, state = reset(jax.random.split(jax.random.key(1), 400), params)
    layout = jax.vmap(env.layout)(state)
    bank = np.asarray(params.map_bank)
    positions = np.concatenate([layout["agent_xy"][:, None], layout["zone_xy"]], axis=1)
    images = np.stack(
        [np.stack(f(bank[..., 0], bank[..., 1]), axis=-1) for f in D4]
    )  # [8, M, N, 2]
    close = np.abs(positions[:, None, None] - images[None]).max(axis=(-1, -2)) < 1e-6  # [R, 8, M]
    assert close.any(axis=(1, 2)).all(), "a reset layout is no image of a bank entry"
    assert close.any(axis=(0, 2)).all()  # every symmetry occurs
    yaw = np.asarray(layout["agent_yaw"])
    assert len(np.unique(yaw.round(6))) == 400  # fresh yaw for every episode
    direction = np.asarray(layout["zone_direction"])
    assert set(np.unique(direction[:, env.zone_moving])) == {-1.0, 1.0}
    assert (direction[:, ~env.zone_moving] == 0).all()


def test_from_bank_images_keep_the_distances():
    bank = jax.random.uniform(jax.random.key(2), (3, 5, 2), minval=-2, maxval=2)
    images = jax.vmap(lambda k: from_bank(k, bank))(jax.random.split(jax.random.key(3), 64))
    dist = lambda p: np.linalg.norm(p[:, :, None] - p[:, None, :], axis=-1)
    norms = np.sort(dist(np.asarray(images)).reshape(64, -1), axis=1)
    reference = np.sort(dist(np.asarray(bank)).reshape(3, -1), axis=1)
    assert all(np.isclose(reference, n, atol=1e-5).all(axis=1).any() for n in norms)


# ---- MuJoCo Warp through MJX ---------------------------------------------------------------
needs_warp = pytest.mark.skipif(not warp_available(), reason="warp-lang is not installed")


def member(tree, i: int):
    return jax.tree.map(lambda x: x[i], tree)


@needs_warp
def test_warp_nested_batches_match_single_worlds():
    """The custom batching rule folds nested vmaps into one batch of worlds (one contact
    buffer for all): every world must come out as when stepped alone."""
    env, params = specrl_jax.make("CarLTL0-v0", physics="warp")
    physics: Physics = env.physics
    _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(
        jax.random.split(jax.random.key(0), 4), params
    )
    ctrl = jax.random.uniform(jax.random.key(1), (4, 2), minval=-1, maxval=1)
    one = jax.jit(physics.step)
    alone = [one(member(state.physics, i), ctrl[i]) for i in range(4)]
    nested = jax.jit(jax.vmap(jax.vmap(physics.step)))(
        jax.tree.map(lambda x: x.reshape(2, 2, *x.shape[1:]), state.physics), ctrl.reshape(2, 2, 2)
    )
    flat = jax.tree.map(lambda x: x.reshape(4, *x.shape[2:]), nested)
    for i in range(4):
        got = member(flat, i)
        np.testing.assert_allclose(got.qpos, alone[i].qpos, atol=1e-6)
        np.testing.assert_allclose(got.sensordata, alone[i].sensordata, rtol=1e-4, atol=1e-4)
    assert float(jnp.abs(alone[0].qpos[:2] - state.physics.qpos[0, :2]).max()) > 0.0


@needs_warp
def test_warp_tracks_mujoco_c_from_a_settled_car():
    """From a Car at rest on its wheels (200 substeps of MuJoCo C), 10 env steps of random
    actions: MuJoCo Warp stays with MuJoCo C (measured ~1e-6 m; from the env's start, where the
    wheels exactly touch the floor, the first contact differs, see docs/fidelity.md)."""
    env, params = specrl_jax.make("CarLTL0-v0", physics="warp")
    physics: Physics = env.physics
    _, state = jax.jit(env.reset)(jax.random.key(4), params)
    data = mujoco.MjData(env.mj_model)
    data.qpos[:] = np.asarray(state.start_qpos, np.float64)
    for _ in range(200):
        mujoco.mj_step(env.mj_model, data)
    start = jax.jit(physics.init)(jnp.asarray(data.qpos, jnp.float32))
    sim = start.replace(
        qvel=jnp.asarray(data.qvel, jnp.float32),
        qacc_warmstart=jnp.asarray(data.qacc_warmstart, jnp.float32),
    )
    step = jax.jit(physics.step)
    for a in np.random.default_rng(0).uniform(-1, 1, (10, 2)).astype(np.float32):
        sim = step(sim, jnp.asarray(a))
        data.ctrl[:] = a
        for _ in range(10):
            mujoco.mj_step(env.mj_model, data)
        mujoco.mj_forward(env.mj_model, data)
    assert np.linalg.norm(data.xpos[1, :2] - np.asarray(state.start_qpos[:2])) > 0.02  # it moved
    np.testing.assert_allclose(np.asarray(sim.agent_pos), data.xpos[1], atol=1e-4)


@needs_warp
def test_warp_ant_contacts_take_mujoco_cs_frame():
    """A Warp Ant gives MuJoCo Warp C's capsule-plane frame (process-wide): at a settled Ant
    state (4 foot contacts, capsules ~10 degrees from the floor normal) Warp's forward pass
    has C's contact frames and C's accelerations under the original's pyramidal cone (Warp's
    own frame, world y as first tangent, departs by 12% of qacc there: docs/fidelity.md)."""
    from specrl_jax.envs.zone import warp_contact_frame
    from specrl_jax.envs.zone.mjx_import import mjx
    from specrl_jax.envs.zone.models import load_model

    env, _ = specrl_jax.make("AntLTL0-v0", physics="warp")
    assert env.physics.c_contact_frame and warp_contact_frame.installed()
    assert not Physics(load_model("Car"), backend="warp").c_contact_frame  # no capsules
    model = env.mj_model
    data = settled_ant(model)
    forward = jax.jit(mjx.forward)(
        mjx.put_model(model, impl="warp"),
        mjx.put_data(model, data, impl="warp", naconmax=16, njmax=64),
    )
    impl = forward._impl
    count = int(np.asarray(impl.nacon)[0])
    pos, frames = np.asarray(impl.contact__pos)[:count], np.asarray(impl.contact__frame)[:count]
    match = [int(np.argmin(np.abs(pos - p).sum(1))) for p in data.contact.pos]
    assert count == 4 and sorted(match) == [0, 1, 2, 3]
    np.testing.assert_allclose(frames[match].reshape(-1, 9), data.contact.frame, atol=1e-6)
    error = np.abs(np.asarray(forward.qacc) - data.qacc).max() / np.abs(data.qacc).max()
    assert error < 1e-5, error


@needs_warp
def test_warp_contact_frame_refuses_an_unexpected_mujoco_warp(monkeypatch):
    """An MJX whose MuJoCo Warp has no capsule-plane function where we expect it fails loudly
    (the Ant would otherwise silently keep Warp's frame)."""
    from specrl_jax.envs.zone import warp_contact_frame

    monkeypatch.setattr(warp_contact_frame, "_PRIMITIVE_COLLISIONS", {})
    with pytest.raises(RuntimeError, match="not laid out as specrl_jax's capsule contact frame"):
        warp_contact_frame.install()
