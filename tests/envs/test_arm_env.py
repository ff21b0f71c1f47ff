"""ArmEnv: IDs, spaces, stepping contract, layouts, errors, and the Gymnasium bridge.

Most tests share one compiled step (mode 1 without table contacts: the contact pairs triple the
compile time on a CPU); the Gymnasium checker compiles one ID of each mode and control (a
`.partial` ID has its full-view ID's spaces), the mode-1 joint ID with table contacts."""

import warnings

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import scipy.stats
from gymnasium.utils.env_checker import check_env
from xla_options import OPTIMISED

import specrl_jax
from specrl_jax.envs.arm import ArmConfig, ArmEnv
from specrl_jax.envs.arm import layout as layout_lib
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


# The original's sampler, rebuilt from reference B3 alone (no specrl_jax.envs.arm.layout): the
# box, the 100 tries per region, the separation, and the robot keep-out measured by MuJoCo C on
# the arm's MJCF (used as data: link frames and hull files) at the neutral pose.
NEUTRAL_JOINTS = (0.00, 0.41, 0.00, -1.85, 0.00, 2.26, 0.79)  # B2
KEEPOUT_HULLS = ("link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand",
                 "leftfinger", "rightfinger")  # PyBullet links -1, 0..6, 8, 9, 10
FRAME_ONLY = {"link8": (0.03844, 0.0, 0.3024), "grasptarget": (0.03844, 0.0, 0.1974)}  # 7, 11 (B6)


class _ReferenceKeepout:
    """B3's robot keep-out: a region fails if a keep-out hull comes within `keepout` of its sphere
    (MuJoCo's `mj_geomDistance` to the whole hull), or if a frame-only link's origin comes within
    `keepout + radius` (the original's 0.14 m) of its centre."""

    def __init__(self, radius, keepout):
        spec = mujoco.MjSpec.from_file(str(arm_model.MODEL_PATH))
        for mesh in spec.meshes:
            mesh.maxhullvert = -1  # whole hulls (the physics model caps them for table contacts)
        spec.worldbody.add_geom(name="region", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                                size=[radius, 0, 0])
        self.model, self.radius, self.keepout = spec.compile(), radius, keepout
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = NEUTRAL_JOINTS
        mujoco.mj_kinematics(self.model, self.data)
        self.hulls = np.array([self.model.geom(name).id for name in KEEPOUT_HULLS])
        self.sphere = self.model.geom("region").id
        self.frames = np.array([self.data.xpos[self.model.body("link8").id],
                                self.data.site_xpos[self.model.site("grasptarget").id]])
        assert np.abs(self.frames - np.array(list(FRAME_ONLY.values()))).max() < 1e-4

    def clear(self, centres, slack=0.0):
        """bool[N]: which of `centres: float[N, 3]` pass (with `slack` metres of tolerance)."""
        reach = self.keepout + self.radius - slack
        clear = np.linalg.norm(centres[:, None] - self.frames, axis=-1).min(1) > reach
        # a hull's bounding sphere farther than `reach` settles it without MuJoCo
        near = (np.linalg.norm(centres[:, None] - self.data.geom_xpos[self.hulls], axis=-1)
                - self.model.geom_rbound[self.hulls]) <= reach
        for i in np.flatnonzero(clear):
            self.data.geom_xpos[self.sphere] = centres[i]  # read as is by mj_geomDistance
            clear[i] = all(
                mujoco.mj_geomDistance(self.model, self.data, hull, self.sphere, 1.0, None)
                > self.keepout - slack for hull in self.hulls[near[i]])
        return clear


def _reference_layouts(rng, n, config, keepout, batch=4096):
    """`n` layouts float64[n, Z, 3] drawn as B3 says the original draws them.

    Regions are placed one by one, each taking the first of up to `max_tries` uniform draws in the
    box x [-0.5, 0.2], y [-0.3, 0.3], z [r, r + 0.5] whose centre is at least `keepout + 2 r`
    from every region placed; a region with no such draw throws the layout away. A placed layout
    is thrown away whole if any region fails the robot keep-out. `batch` layouts go side by side,
    draw by draw; survivors are kept in order until there are `n`. `keepout` is the config's
    `_ReferenceKeepout`.
    """
    r, z = config.region_radius, config.num_regions
    low, high = np.array([-0.5, -0.3, r]), np.array([0.2, 0.3, r + 0.5])
    separation = config.keepout + 2 * r
    accepted = []
    while sum(map(len, accepted)) < n:
        centres = np.zeros((batch, z, 3))
        placed = np.ones(batch, bool)
        for region in range(z):
            waiting = np.arange(batch)[placed]
            for _ in range(config.max_tries):
                draw = rng.uniform(low, high, (len(waiting), 3))
                gaps = np.linalg.norm(draw[:, None] - centres[waiting, :region], axis=-1)
                apart = (gaps >= separation).all(1)
                centres[waiting[apart], region] = draw[apart]
                waiting = waiting[~apart]
                if not len(waiting):
                    break
            placed[waiting] = False
        for region in range(z):  # the whole layout is tested; region by region only saves work
            alive = np.flatnonzero(placed)
            placed[alive] = keepout.clear(centres[alive, region])
        accepted.append(centres[placed])
    return np.concatenate(accepted)[:n]


def _layout_statistics(centres):
    """One number per layout for each statistic of `centres: float[N, Z, 3]` (so the samples of a
    statistic are independent): every region's x, y, z, the layout's mean x, |y| and z, its
    closest pair, mean nearest-neighbour and mean pairwise centre distance."""
    z = centres.shape[1]
    gaps = np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1)
    first, second = np.triu_indices(z, 1)
    pairs = gaps[:, first, second]
    nearest = np.where(np.eye(z, dtype=bool), np.inf, gaps).min(-1)
    stats = {f"{'xyz'[axis]} of region {i}": centres[:, i, axis]
             for i in range(z) for axis in range(3)}
    stats.update({
        "mean x": centres[..., 0].mean(1), "mean |y|": np.abs(centres[..., 1]).mean(1),
        "mean z": centres[..., 2].mean(1), "closest pair": pairs.min(1),
        "mean nearest neighbour": nearest.mean(1), "mean pair distance": pairs.mean(1),
    })
    return stats


def _assert_same_distribution(ours, ref, alpha=1e-4):
    """Two-sample KS on each `_layout_statistics`: D stays below the level-`alpha` bound of the
    asymptotic Kolmogorov tail, P(D > c sqrt(1/n + 1/m)) ~ 2 exp(-2 c^2), so a correct sampler
    fails by chance with probability at most `alpha` x (number of statistics)."""
    bound = np.sqrt(np.log(2 / alpha) / 2 * (1 / len(ours) + 1 / len(ref)))
    ours_stats, ref_stats = _layout_statistics(ours), _layout_statistics(ref)
    distances = {name: scipy.stats.ks_2samp(ours_stats[name], ref_stats[name]).statistic
                 for name in ours_stats}
    worst = max(distances, key=distances.get)
    assert distances[worst] < bound, (worst, distances[worst], bound)


def _assert_valid(centres, config, keepout):
    """Every layout of `centres: float[N, Z, 3]` lies in the box, keeps its regions apart and
    passes the reference keep-out (within 1 mm: our hull distance is float32)."""
    r = config.region_radius
    assert (centres >= np.array([-0.5, -0.3, r]) - 1e-6).all()
    assert (centres <= np.array([0.2, 0.3, r + 0.5]) + 1e-6).all()
    gaps = np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1)
    gaps += np.eye(centres.shape[1]) * 9
    assert gaps.min() >= config.keepout + 2 * r - 1e-6, gaps.min()
    inside = ~keepout.clear(centres.reshape(-1, 3), slack=1e-3)
    assert not inside.any(), f"{inside.sum()} centres inside the robot keep-out"


#: layouts per call of the compiled sampler below: under `vmap` its rejection loop runs until the
#: slowest layout of the batch is placed, so 400 at once run about twice as long as 50 calls of 8
#: (each layout depends on its key alone: the same layouts either way)
SAMPLE_CHUNK = 8


def _sample_layouts(config, keys):
    """(float64[N, Z, 3] centres, bool[N] ok) of `sample_centres` for each of `keys`,
    `SAMPLE_CHUNK` at a time through one program (OPTIMISED: it runs 3x faster than at level 0)."""
    sample = jax.jit(jax.vmap(lambda k: layout_lib.sample_centres(k, config)),
                     compiler_options=OPTIMISED)
    parts = [sample(keys[i:i + SAMPLE_CHUNK]) for i in range(0, len(keys), SAMPLE_CHUNK)]
    return (np.concatenate([np.asarray(centres, np.float64) for centres, _ in parts]),
            np.concatenate([np.asarray(ok) for _, ok in parts]))


def test_layouts_are_valid_and_distributed_as_the_original_sampler(monkeypatch):
    """Our sampler (jit + vmap) against the plain numpy reference above, on the benchmark's
    config (8 regions), then on 2 regions with one try per block, one continuation slot and two
    exact tests per round, so that the rationing rules of `place_round` and `sample_centres`
    decide often (they bind in few rounds of the default config)."""
    # 400 layouts of ours, 800 of the reference: KS bound 0.136. Without the robot keep-out the
    # mean |y| moves by D ~ 0.65, with a separation of 0.18 or 0.22 m (not 0.2) the closest pair
    # by D ~ 0.6; a correct sampler's largest D of the 30 statistics was 0.07-0.10 (6 seeds)
    config = ArmConfig()
    keepout = _ReferenceKeepout(config.region_radius, config.keepout)
    box = np.random.default_rng(2).uniform([-0.5, -0.3, 0.06], [0.2, 0.3, 0.56], (4000, 3))
    assert abs(keepout.clear(box).mean() - 0.543) < 0.03  # B3's measured share of the box
    ours, ok = _sample_layouts(config, jax.random.split(jax.random.key(0), 400))
    assert ok.all() and ours.shape == (400, 8, 3)
    _assert_valid(ours, config, keepout)
    ref = _reference_layouts(np.random.default_rng(0), 800, config, keepout)
    _assert_same_distribution(ours, ref)

    # 400 layouts of ours, 2000 of the reference: KS bound 0.122; largest D of a correct
    # sampler 0.072
    monkeypatch.setattr(layout_lib, "TRY_BLOCK", 1)
    config = ArmConfig(colors=("magenta", "blue"), regions_per_color=1, layouts_per_round=8,
                       exact_checks_per_round=2, continuation_slots=1)
    keepout = _ReferenceKeepout(config.region_radius, config.keepout)
    ours, ok = _sample_layouts(config, jax.random.split(jax.random.key(1), 400))
    assert ok.all()
    _assert_valid(ours, config, keepout)
    ref = _reference_layouts(np.random.default_rng(1), 2000, config, keepout)
    _assert_same_distribution(ours, ref)


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


# one ID per mode: the .partial variants differ only in the feature scaling (test_arm_geometry)
# and each checker run compiles the arm's step (about a minute on a 2-core CPU); the mode-1 one
# with the original's table contacts (contacts triple the CPU compile: once in this file)
@pytest.mark.parametrize("env_id", IDS[::3])
def test_gymnasium_bridge_gives_the_original_dict(env_id):
    import specrl_jax.gym  # noqa: F401  (registers the IDs)

    contacts = env_id == "PandaLTLReach1Joints-v0.partial"
    env = gymnasium.make(env_id, table_contacts=contacts, layouts_per_round=64)
    assert env.unwrapped.env.config.table_contacts == contacts
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


#: the registered Panda IDs of the modes and controls the checker has not seen above or in
#: test_arm_ik.py (a `.partial` ID has the spaces of its full-view ID, its feature scaling tested
#: in test_arm_geometry)
OTHER_IDS = sorted({i.removesuffix(".partial") for i in list_envs() if i.startswith("Panda")}
                   - {IDS[0], IDS[3].removesuffix(".partial"), "PandaLTLReach0-v0"})


@pytest.mark.slow  # about half a minute on a 2-core CPU: the ID compiles its reset and step
@pytest.mark.parametrize("env_id", OTHER_IDS)
def test_gymnasium_checker_passes_on_the_other_ids(env_id):
    """Gymnasium's checker on the rest of the registered Panda modes (end-effector control with
    the link features)."""
    import specrl_jax.gym  # noqa: F401  (registers the IDs)

    assert OTHER_IDS == ["PandaLTLReach1-v0"]
    env = gymnasium.make(env_id, table_contacts=False, layouts_per_round=64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
