"""ArmEnv: IDs, spaces, stepping contract, layouts, errors, and the Gymnasium bridge.

Most tests share one compiled step (mode 1 without table contacts: the contact pairs triple the
compile time on a CPU); the Gymnasium checker compiles each registered ID once (one of them
with table contacts, the rest without; marked slow)."""

import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import specrl_jax
from specrl_jax.envs.arm import ArmConfig, ArmEnv, layout as layout_lib
from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.registry import list_envs

IDS = ("PandaLTLReach0Joints-v0", "PandaLTLReach0Joints-v0.partial",
       "PandaLTLReach1Joints-v0", "PandaLTLReach1Joints-v0.partial")


def test_ids_build_with_the_declared_shapes():
    for env_id in IDS:
        env, params = specrl_jax.make(env_id)
        mode = int(env_id[13])
        assert env.config.mode == mode and env.config.partial == env_id.endswith(".partial")
        assert params.max_steps == 200 and env.obs_kinds == {"ap": "range_bearing", "ego": "vector"}
        p = 4 if mode == 0 else 8
        assert env.num_propositions == p and env.alphabet.shape[1] == p
        assert env.observation_space["ego"].shape == ((6,) if mode == 0 else (70,))
        assert env.observation_space["ap"].shape == ((4, 4) if mode == 0 else (8, 8, 4))
    env, _ = specrl_jax.make("PandaLTLReach1Joints-v0")
    assert env.propositions[:4] == ("arm_blue", "arm_green", "arm_magenta", "arm_yellow")
    assert env.alphabet.shape == (256, 8)  # several mode-1 propositions can hold together


def test_bad_configs_and_actions_raise_clear_errors():
    with pytest.raises(ValueError, match="mode must be 0"):
        ArmConfig(mode=2)
    with pytest.raises(ValueError, match="colors must be distinct"):
        ArmConfig(colors=("magenta", "magenta"))
    with pytest.raises(ValueError, match="cannot fit"):
        ArmConfig(regions_per_color=40)
    with pytest.raises(ValueError, match="region_radius"):
        ArmConfig(region_radius=0.0)
    with pytest.raises(ValueError, match="fixed by the env ID"):
        specrl_jax.make("PandaLTLReach0Joints-v0", mode=1)
    with pytest.raises(ValueError, match="unknown ArmParams"):
        specrl_jax.make("PandaLTLReach0Joints-v0", max_step=3)
    with pytest.raises(ValueError, match=r"0\.0% of the sampling box .* keepout 0\.3 m"):
        specrl_jax.make("PandaLTLReach0Joints-v0", keepout=0.3)
    env = ArmEnv(ArmConfig(mode=1, table_contacts=False))
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        env.action_space.check(jnp.zeros(3))
    with pytest.raises(TypeError, match="floating"):
        env.action_space.check(jnp.zeros(7, jnp.int32))
    with pytest.raises(ValueError, match="NaN"):
        env.action_space.check(jnp.full(7, jnp.nan))


def test_keepout_feasibility_is_checked_at_build():
    """A keep-out that leaves no (or too few) valid centres in the sampling box is refused when
    the env is built, saying how much of the box passes; the defaults build, and the check's
    Monte Carlo agrees with the reference's measured 54.3 % for them."""
    for keepout in (0.2, 0.4, 0.6):
        with pytest.raises(ValueError, match=r"too little room for 8 regions: \d+\.\d% of the "
                                             r"sampling box .*accepted: "):
            ArmEnv(ArmConfig(keepout=keepout))
    with pytest.raises(ValueError, match="0.0% of the sampling box"):
        ArmEnv(ArmConfig(keepout=0.4))
    ArmEnv(ArmConfig())
    ArmEnv(ArmConfig(colors=("magenta",), keepout=0.2))  # rarer centres, but only two regions
    exact = layout_lib.keepout_pass_fraction(0.06, 0.08)
    assert abs(exact - 0.543) < 0.07  # 3 standard errors of 512 points
    assert 0.3 < layout_lib.grid_clear_fraction(0.06, 0.08) <= exact


def _placement_reference(rng, config, n):
    """Plain-Python transcription of the original's sampler (sequential placement with per-region
    retries, then whole-layout rejection by the robot keep-out)."""
    low = np.array([-0.5, -0.3, config.region_radius])
    high = np.array([0.2, 0.3, config.region_radius + 0.5])
    keep = jax.jit(jax.vmap(lambda c: layout_lib.keepout_ok(c, config)))
    out = []
    while len(out) < n:
        batch = []
        for _ in range(64):
            centres = []
            for _ in range(config.num_regions):
                for _ in range(config.max_tries):
                    c = rng.uniform(low, high)
                    if all(np.linalg.norm(c - o) >= config.keepout + 2 * config.region_radius
                           for o in centres):
                        centres.append(c)
                        break
                else:
                    break
            if len(centres) == config.num_regions:
                batch.append(centres)
        ok = np.asarray(keep(np.asarray(batch).reshape(-1, 3))).reshape(len(batch), -1).all(1)
        out += [b for b, good in zip(batch, ok) if good]
    return np.asarray(out[:n])


def test_layouts_are_valid_and_distributed_as_the_original_sampler(monkeypatch):
    # two regions of the benchmark's size, so the reference accepts often enough for a CPU
    # test; the sampler uses the stored keep-out grid with few exact checks per round, and one
    # try per block with one continuation slot, so the rationing rules are exercised often
    monkeypatch.setattr(layout_lib, "TRY_BLOCK", 1)
    config = ArmConfig(colors=("magenta", "blue"), regions_per_color=1, layouts_per_round=8,
                       exact_checks_per_round=2, continuation_slots=1)
    sample = jax.jit(jax.vmap(lambda k: layout_lib.sample_centres(k, config)))
    ours, ok = sample(jax.random.split(jax.random.key(0), 400))
    ours = np.asarray(ours)
    assert np.asarray(ok).all()
    assert np.asarray(jax.jit(jax.vmap(jax.vmap(lambda c: layout_lib.keepout_ok(c, config))))(ours)).all()
    assert (np.linalg.norm(ours[:, 0] - ours[:, 1], axis=-1) >= 0.2 - 1e-6).all()
    ref = _placement_reference(np.random.default_rng(0), config, 400)
    for stat in (lambda x: x[..., 0], lambda x: x[..., 2], lambda x: np.abs(x[..., 1])):
        a, b = stat(ours).ravel(), stat(ref).ravel()
        stderr = np.sqrt(a.var() / a.size + b.var() / b.size)
        assert abs(a.mean() - b.mean()) < 4 * stderr


def test_keepout_grid_is_conservative():
    """The stored grid's CLEAR and BAD cells agree with the exact keep-out test everywhere in
    them (random points, and points at cell corners, where the margin is farthest from the
    cell centre's), and the grid settles most of the box."""
    config = ArmConfig()
    classes, low, cell = layout_lib.keepout_grid(config.region_radius, config.keepout)
    assert layout_lib._grid_path(config.region_radius, config.keepout).exists()
    assert (classes == layout_lib.UNSURE).mean() < 0.12
    rng = np.random.default_rng(5)
    points = rng.uniform([-0.5, -0.3, 0.06], [0.2, 0.3, 0.56], (3000, 3))
    index = rng.integers(0, classes.shape, (1000, 3))
    corners = low + (index + rng.integers(0, 2, (1000, 3)) * (1 - 1e-6)) * cell
    points = np.concatenate([points, corners]).astype(np.float32)
    cls = np.asarray(layout_lib.grid_class(jnp.asarray(points), config))
    exact = np.asarray(jax.jit(jax.vmap(lambda c: layout_lib.keepout_ok(c, config)))(points))
    assert exact[cls == layout_lib.CLEAR].all() and not exact[cls == layout_lib.BAD].any()
    assert (cls == layout_lib.UNSURE).mean() < 0.12


def test_benchmark_layout_keeps_regions_apart_and_off_the_robot():
    env, params = specrl_jax.make("PandaLTLReach0Joints-v0")
    centres, ok = jax.jit(lambda k: layout_lib.sample_centres(k, env.config))(jax.random.key(3))
    centres = np.asarray(centres)
    assert bool(ok) and centres.shape == (8, 3)
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.eye(8)
    assert gaps.min() >= 0.2 - 1e-6
    assert (centres[:, 2] >= 0.06).all() and (centres[:, 2] <= 0.56).all()


@pytest.fixture(scope="module")
def stepping():
    env = ArmEnv(ArmConfig(mode=1, table_contacts=False, horizon=3))
    params = env.default_params
    step = jax.jit(env.step)
    centres = np.array([[0.2, 0.2 * i - 0.3, 0.55] for i in range(4)] +
                       [[-0.3, 0.2 * i - 0.3, 0.06] for i in range(4)])  # away from the arm
    reset_to = jax.jit(env.reset_to)
    return env, params, step, reset_to, centres


def test_step_contract_determinism_vmap_and_horizon(stepping):
    env, params, step, reset_to, centres = stepping
    obs, state = reset_to(jax.random.key(0), {"region_pos": centres}, params)
    assert env.observation_space["ego"].shape == obs["ego"].shape
    assert obs["ap"].shape == env.ap_shape and obs["ap"].dtype == jnp.float32
    actions = jax.random.uniform(jax.random.key(1), (3, 7), minval=-1, maxval=1)
    keys = jax.random.split(jax.random.key(2), 3)
    trajectory, s = [], state
    for t in range(3):
        o, s, reward, terminated, truncated, info = step(keys[t], s, actions[t], params)
        trajectory.append((o, s))
        assert float(reward) == 0.0 and not bool(terminated)
        assert bool(truncated) == (t == 2)  # horizon 3 truncates, never terminates
        assert info["propositions"].shape == (8,) and info["propositions"].dtype == jnp.bool_
    # same inputs, same outputs
    o2, s2, *_ = step(keys[0], state, actions[0], params)
    assert np.array_equal(np.asarray(o2["ap"]), np.asarray(trajectory[0][0]["ap"]))
    # the step moved the arm by about 0.05 a per joint (the motor's gain)
    moved = np.asarray(trajectory[0][1].physics.qpos - state.physics.qpos)
    commanded = 0.05 * np.asarray(actions[0])
    assert (np.abs(moved) <= np.abs(commanded) * 1.2 + 1e-3).all()  # joint 5 (12 N m) lags
    assert np.median(moved / commanded) > 0.6
    # one compiled batch of world steps (`step_env`, no action check) for the last two claims
    wild = jnp.array([jnp.nan, 5.0, -5.0, 0.0, 0.0, 0.0, 0.0])
    tame = jnp.array([0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0])
    batch_state = jax.tree.map(lambda x: jnp.stack([x] * 4), state)
    batch_keys = jnp.stack([keys[0], keys[1], keys[0], keys[0]])
    bo, bs, *_ = jax.jit(jax.vmap(env.step_env, in_axes=(0, 0, 0, None)))(
        batch_keys, batch_state, jnp.stack([actions[0], actions[1], wild, tame]), params)
    # a vmapped batch equals its members
    one, *_ = step(keys[1], state, actions[1], params)
    assert np.abs(np.asarray(bo["ego"][1]) - np.asarray(one["ego"])).max() < 1e-5
    assert np.abs(np.asarray(bo["ego"][0]) - np.asarray(trajectory[0][0]["ego"])).max() < 1e-5
    # NaN and out-of-range values on the traced path: NaN counts as 0, the rest is clipped
    assert np.array_equal(np.asarray(bs.physics.qpos[2]), np.asarray(bs.physics.qpos[3]))


def test_layout_round_trip_and_labels_after_a_step(stepping):
    env, params, step, reset_to, centres = stepping
    obs, state = reset_to(jax.random.key(0), {"region_pos": centres}, params)
    layout = env.layout(state)
    assert np.array_equal(np.asarray(layout["region_pos"]), centres.astype(np.float32))
    assert list(np.asarray(layout["region_color"])) == [0, 0, 1, 1, 2, 2, 3, 3]
    np.testing.assert_allclose(layout["joint_qpos"], arm_model.NEUTRAL_QPOS, atol=1e-6)
    obs2, state2 = reset_to(jax.random.key(9), layout, params)
    np.testing.assert_allclose(obs2["ego"], obs["ego"], atol=1e-6)
    # a magenta region around the fingertips: after a zero-action step both fingers and the
    # hand touch it
    tip = np.asarray(env.poses(state)["link_pos"][8]) + np.array([0, 0, -0.03])
    near = centres.copy()
    near[0] = tip
    _, state = reset_to(jax.random.key(0), {"region_pos": near}, params)
    _, _, _, _, _, info = step(jax.random.key(1), state, jnp.zeros(7), params)
    on = {p for p, v in zip(env.propositions, np.asarray(info["propositions"])) if v}
    assert on == {"arm_magenta", "grippers_magenta"}


# one ID per mode: the .partial variants differ only in the feature scaling (tested above) and
# each checker run compiles the arm's step (about a minute on a 2-core CPU)
@pytest.mark.parametrize("env_id", IDS[::3])
def test_gymnasium_bridge_gives_the_original_dict(env_id):
    import specrl_jax.gym  # noqa: F401  (registers the IDs)

    env = gymnasium.make(env_id, table_contacts=False, layouts_per_round=64)
    keys = list(env.unwrapped.env.original_observation_space.spaces)  # gymnasium sorts them
    colors = ("magenta", "yellow", "blue", "green")
    if "0Joints" in env_id:
        assert sorted(keys) == sorted(["ego_state"] + [f"dist_to_{c}" for c in colors])
    else:
        assert sorted(keys) == sorted(
            ["ego_state"] + [f"dist_to_{p}_{c}" for c in colors for p in ("arm", "grippers")])
        assert env.observation_space["dist_to_arm_blue"].shape == (8, 4)
        assert env.observation_space["dist_to_grippers_blue"].shape == (2, 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and info == {"propositions": set()}
    if "0Joints" in env_id:
        np.testing.assert_allclose(obs["ego_state"], [0.03844, 0, 0.1974, 0, 0, 0], atol=1e-4)
    obs, reward, terminated, truncated, info = env.step(np.zeros(7, np.float32))
    assert reward == 0.0 and not terminated and not truncated
    assert info["propositions"] <= set(env.unwrapped.propositions)


#: the registered Panda IDs the checker has not seen above or in test_arm_ik.py
OTHER_IDS = sorted(i for i in set(list_envs()) - {IDS[0], IDS[3], "PandaLTLReach0-v0"}
                   if i.startswith("Panda"))


@pytest.mark.slow  # about 2 min on a 2-core CPU: each ID compiles its reset and step
@pytest.mark.parametrize("env_id", OTHER_IDS)
def test_gymnasium_checker_passes_on_the_other_ids(env_id):
    """Gymnasium's checker on the rest of the registered Panda IDs; one with the original's
    table contacts (the others without: contacts triple the CPU compile)."""
    import specrl_jax.gym  # noqa: F401  (registers the IDs)

    assert len(OTHER_IDS) == 5
    contacts = env_id == "PandaLTLReach1Joints-v0"
    env = gymnasium.make(env_id, table_contacts=contacts, layouts_per_round=64)
    assert env.unwrapped.env.config.table_contacts == contacts
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
