"""The arm's emulated PyBullet position motor: the box-limited motor problem, one env step
against MuJoCo C under the same control law, and the original's measured tracking gains."""

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from scipy.optimize import minimize

from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.physics import MOTOR_RATE, Physics, PhysicsState, motor_torque

H = 0.002


def _box_qp_torque(mass, free_accel, qvel, qpos, target, limit, joint_range=None):
    """Reference: the motor's torques as the minimiser of 1/2 t' M^-1 t - want' t in the box
    (the optimality conditions are the velocity-motor LCP), by L-BFGS-B. With `joint_range`
    ([7, 2] rad), the net force f = tau + down + up of the motor and joint-limit rows: the
    minimiser of 1/2 f' M^-1 f - want' tau - top' down - bottom' up with upper-limit forces
    down <= 0 and lower-limit forces up >= 0, whose optimality conditions are the limit rows'
    complementarity (the joint reaches at most its limit within the substep)."""
    inverse = np.linalg.inv(mass)
    accel = lambda speed: (speed - qvel) / H - free_accel
    want = accel(MOTOR_RATE * (target - qpos))
    rows, bounds = [want], list(zip(-limit, limit))
    if joint_range is not None:
        rows += [accel((joint_range[:, 1] - qpos) / H), accel((joint_range[:, 0] - qpos) / H)]
        bounds += [(None, 0.0)] * 7 + [(0.0, None)] * 7
    rows = np.concatenate(rows)

    def objective(x):
        f = x.reshape(-1, 7).sum(0)
        g = inverse @ f
        return 0.5 * f @ g - rows @ x, np.tile(g, len(x) // 7) - rows

    result = minimize(objective, np.zeros(len(rows)), jac=True, bounds=bounds, method="L-BFGS-B",
                      options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 20000})
    return result.x.reshape(-1, 7).sum(0)


def _c_step(model, data, target, substeps=20):
    """One env step on MuJoCo C from rest on the constraints (no earlier contact force): each
    substep, the reference motor torques with the previous substep's constraint forces counted
    as known (as `Physics.substep`), then mj_step."""
    constraint = np.zeros(7)
    for _ in range(substeps):
        mujoco.mj_forward(model, data)
        mass = np.zeros((7, 7))
        mujoco.mj_fullM(model, data, mass)
        free_accel = np.linalg.solve(mass, data.qfrc_passive - data.qfrc_bias + constraint)
        data.qfrc_applied[:] = _box_qp_torque(mass, free_accel, data.qvel, data.qpos, target,
                                              arm_model.FORCE_LIMITS, model.jnt_range[:7])
        mujoco.mj_step(model, data)
        constraint = data.qfrc_constraint.copy()


def test_motor_torque_solves_the_box_problem():
    rng = np.random.default_rng(0)
    solve = jax.jit(motor_torque, static_argnums=(6,))
    for _ in range(5):
        a = rng.normal(size=(7, 7))
        mass = a @ a.T + 0.5 * np.eye(7)
        args = (mass, rng.normal(0, 5, 7), rng.normal(0, 0.3, 7), np.zeros(7),
                rng.uniform(-0.05, 0.05, 7))
        limit = rng.uniform(5, 60, 7)
        ours = np.asarray(solve(*[jnp.asarray(x, jnp.float32) for x in args],
                                jnp.asarray(limit, jnp.float32), H))
        ref = _box_qp_torque(*args, limit)
        assert np.all(np.abs(ours) <= limit + 1e-3)
        assert np.abs(ours - ref).max() < 2e-2 * limit.max()
        assert np.sum(np.abs(ref) > limit - 1e-6) > 0  # the bound was active


def test_motor_solve_kernel_equals_the_jnp_sweeps_and_lowers_for_a_gpu():
    """The Pallas kernel of the motor solve (`solve="pallas"`, run here by Pallas' interpreter)
    gives the jnp sweeps' forces under `vmap`, joint limits active; for a GPU it lowers to one
    Triton kernel (lowered on the CPU host; compiling it needs the GPU); "auto" is the jnp
    sweeps on a CPU."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(6, 7, 7))
    mass = a @ np.swapaxes(a, 1, 2) * 0.1 + 0.5 * np.eye(7)
    args = [jnp.asarray(x, jnp.float32) for x in
            (mass, *(rng.normal(0, 2, (6, 7)) for _ in range(4)))]
    limits = jnp.asarray(arm_model.FORCE_LIMITS, jnp.float32)
    joint_range = jnp.asarray([[-0.5, 0.5]] * 7, jnp.float32)

    def solver(solve):
        return jax.vmap(lambda *x: motor_torque(*x, limits, H, joint_range=joint_range, solve=solve))

    jnp_forces = np.asarray(jax.jit(solver("xla"))(*args))
    np.testing.assert_array_equal(np.asarray(jax.jit(solver("auto"))(*args)), jnp_forces)  # a CPU
    kernel_forces = np.asarray(jax.jit(solver("pallas_interpret"))(*args))
    assert np.abs(jnp_forces).max() > 1e3  # limit forces pushing joints back into range
    np.testing.assert_allclose(kernel_forces, jnp_forces, rtol=1e-5, atol=1e-6 * np.abs(jnp_forces).max())
    text = jax.jit(solver("pallas")).trace(*args).lower(lowering_platforms=("cuda",)).as_text()
    assert text.count("xla.gpu.triton") == 1
    with pytest.raises(ValueError, match="solve='cuda'; choose one of auto, xla, pallas, pallas_interpret"):
        motor_torque(*[x[0] for x in args], limits, H, solve="cuda")


#: the arms of every compiled motor step below (episodes padded to a multiple): one program per
#: physics; at most 4 arms keep the gated solve to one sub-batch size (`compaction.where_needed`;
#: a second size compiles the solve again, half as long again on a CPU)
BATCH = 4


@functools.cache
def _batched_step(physics):
    """`physics`' step of `BATCH` arms toward joint targets `base + 0.05 a`, jitted once."""
    return jax.jit(jax.vmap(lambda s, base, a: physics.step(s, base + 0.05 * a)))


def _arms(tree):
    """`tree` (one arm's arrays) repeated for `BATCH` arms, float32."""
    return jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x, jnp.float32),
                                                   (BATCH, *np.shape(x))), tree)


@pytest.fixture(scope="module")
def physics():
    """Without table contacts (near the neutral pose the arm does not reach the table; the
    contact pairs would triple the compile time on a CPU)."""
    return Physics(arm_model.load_model(table_contacts=False), arm_model.FORCE_LIMITS)


def test_one_env_step_matches_mujoco_c_under_the_same_control(physics):
    model = arm_model.load_model(table_contacts=False)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    step = _batched_step(physics)
    state = physics.init(jnp.asarray(arm_model.NEUTRAL_QPOS, jnp.float32))
    data.qpos[:] = arm_model.NEUTRAL_QPOS
    for _ in range(3):
        target = np.asarray(state.qpos, np.float64) + 0.05 * rng.uniform(-1, 1, 7)
        data.qpos[:], data.qvel[:] = np.asarray(state.qpos), np.asarray(state.qvel)
        _c_step(model, data, target)
        state = step(_arms(state), _arms(target), _arms(np.zeros(7)))
        state = jax.tree.map(lambda x: x[0], state)
        assert np.abs(np.asarray(state.qpos) - data.qpos).max() < 2e-4
        assert np.abs(np.asarray(state.qvel) - data.qvel).max() < 2e-2


#: MuJoCo's default Newton solver, the reference's (C) and the baseline of the caps under test
MUJOCO_SOLVER = {"ls_iterations": 50, "iterations": 100, "tolerance": 1e-8}


def _contact_model(**option):
    """The arm model with 7 of its 13 contact pairs, optionally other solver options
    (`spec.option` attributes): a subset keeps MJX's compile short and still mixes every face
    shape (6-, 5-, 3- and 4-cornered polygons), a mesh shared by two geoms, and both kinds of
    pair."""
    keep = {("link4", "table"), ("link5", "table"), ("link6", "table"), ("leftfinger", "table"),
            ("rightfinger", "table"), ("hand", "floor"), ("link7", "floor")}
    spec = mujoco.MjSpec.from_file(str(arm_model.MODEL_PATH))
    for pair in list(spec.pairs):
        if (pair.geomname1, pair.geomname2) not in keep:
            spec.delete(pair)
    for name, value in option.items():
        setattr(spec.option, name, value)
    return spec.compile()


@functools.cache
def _contact_starts():
    """One env step's starts, float64[50, 7] joint angles, velocities and targets: 48 touching
    the table or floor (less than 1 cm deep, joints moving at up to 1 rad/s), then 2 at joint
    limits (shoulder and elbow next to their lower limits, at rest, targets into the limit)."""
    model = _contact_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(8)
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]
    starts = []
    while len(starts) < 48:
        data.qpos[:] = rng.uniform(low, high)
        mujoco.mj_forward(model, data)
        if data.ncon and data.contact.dist[:data.ncon].min() > -0.01:
            starts.append(data.qpos.copy())
    qvel = rng.uniform(-1.0, 1.0, (len(starts), 7))
    for joint in (1, 3):
        q = arm_model.NEUTRAL_QPOS.copy()
        q[joint] = low[joint] + 0.005
        starts.append(q)
    starts = np.asarray(starts)
    qvel = np.concatenate([qvel, np.zeros((2, 7))])
    targets = starts + 0.05 * rng.choice([-1.0, 1.0], starts.shape)
    targets[-2:, (1, 3)] = starts[-2:, (1, 3)] - 0.05
    return starts, qvel, targets


#: the starts C steps: every 4th contact start and both limit ones (the reference motor's
#: optimiser is slow)
C_CHECKED = [*range(0, 48, 4), 48, 49]


@functools.cache
def _contact_step_mjx(**option):
    """float32[50, 7] joint angles after one MJX env step from `_contact_starts` (zero warm
    start) on `_contact_model(**option)`, every arm solving over every contact (the solver
    settings under test are MuJoCo's; test_arm_solver_gating checks the gated solve over the
    nearest contacts against this one)."""
    starts, qvel, targets = _contact_starts()
    physics = Physics(_contact_model(**option), arm_model.FORCE_LIMITS, solve_capacities=None,
                      solve_pairs=None)
    zeros = jnp.zeros(starts.shape, jnp.float32)
    state = PhysicsState(qpos=jnp.asarray(starts, jnp.float32), qvel=jnp.asarray(qvel, jnp.float32),
                         qacc_warmstart=zeros, qfrc_constraint=zeros)
    step = jax.jit(jax.vmap(physics.step))
    return np.asarray(step(state, jnp.asarray(targets, jnp.float32)).qpos)


@functools.cache
def _contact_step_c():
    """float64[len(C_CHECKED), 7] joint angles after one env step on MuJoCo C (MuJoCo's default
    solver) from the `C_CHECKED` starts."""
    starts, qvel, targets = _contact_starts()
    model = _contact_model(**MUJOCO_SOLVER)
    ref = []
    for q, v, target in zip(starts[C_CHECKED], qvel[C_CHECKED], targets[C_CHECKED]):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:] = q, v
        _c_step(model, data, target)
        ref.append(data.qpos.copy())
    return np.asarray(ref)


def _assert_as_near_c_as_measured(after: dict) -> None:
    """Each `after[name]` (float[50, 7], one step from `_contact_starts`) as near C as
    `arm_checks.py --parts ls_vs_c` measured (MJX's contacts are its own: mm-level, up to
    6e-2 rad in its 975 contact states); limit states within 1e-4 rad."""
    for name, qpos in after.items():
        err = np.abs(qpos[C_CHECKED] - _contact_step_c()).max(1)
        assert np.median(err) < 5e-3 and err.max() < 6e-2 and err[-2:].max() < 1e-4, (name, err)


def test_one_env_step_with_contacts_and_limits_matches_mujoco_c_at_the_line_search_cap():
    """The model's line-search cap (`assets/panda.xml`, MJX's iterations) against MuJoCo's 50
    (MJX, the model's Newton setting) and MuJoCo C (float64, MuJoCo's default solver): one env
    step from `_contact_starts`. The cap lands where 50 does (a cap of 2 departs by 2e-3 rad
    here), and both as near C as measured."""
    assert _contact_model().opt.ls_iterations < 50  # the cap under test
    after = {"cap": _contact_step_mjx(), "50": _contact_step_mjx(ls_iterations=50)}
    assert np.abs(after["cap"] - after["50"]).max() < 1e-5
    _assert_as_near_c_as_measured(after)


def test_one_env_step_with_contacts_and_limits_matches_mujoco_c_at_the_newton_cap():
    """The model's Newton iteration cap and tolerance (`assets/panda.xml`) against MuJoCo's 100
    and 1e-8 (MJX, the model's line search) and MuJoCo C (float64, MuJoCo's default solver):
    one env step from `_contact_starts`. The cap lands where 100 does (within 1.4e-5 rad at one
    of the 50 starts since the pairs take Bullet's friction, bit-identical at the others; caps of
    5 and 3 depart by 2.4e-2 and 1.3e-2 rad here), and both as near C as measured."""
    model = _contact_model()
    assert model.opt.iterations < 100 and model.opt.tolerance == 1e-8  # the cap under test
    after = {"cap": _contact_step_mjx(),
             "100": _contact_step_mjx(iterations=100, tolerance=1e-8)}
    assert np.abs(after["cap"] - after["100"]).max() < 5e-5
    _assert_as_near_c_as_measured(after)


PYBULLET_ROLLOUTS = Path(__file__).parent / "data" / "arm_pybullet_rollouts.npz"


def _rollouts_from_neutral(physics, actions):
    """float32[E, T+1, 7] joint angles of our arm under `actions` float[E, T, 7] (joint control,
    targets `q + 0.05 a`), each episode from the neutral pose at rest; `BATCH` episodes at a
    time (`_batched_step`), the last ones padded with zero actions."""
    step = _batched_step(physics)
    padded = np.zeros((-(-len(actions) // BATCH) * BATCH, *actions.shape[1:]), np.float32)
    padded[:len(actions)] = actions
    episodes = []
    for batch in np.split(padded, len(padded) // BATCH):
        state = _arms(physics.init(jnp.asarray(arm_model.NEUTRAL_QPOS, jnp.float32)))
        qpos = [np.asarray(state.qpos)]
        for t in range(batch.shape[1]):
            state = step(state, state.qpos, jnp.asarray(batch[:, t]))
            qpos.append(np.asarray(state.qpos))
        episodes.append(np.stack(qpos, 1))
    return np.concatenate(episodes)[:len(actions)]


def _gains_and_lags(actions, qpos):
    """float[7, 2]: per joint, the least-squares (gain, lag) of dq_t on 0.05 a_t and
    0.05 a_{t-1}, from `actions` float[E, T, 7] and the joint angles float[E, T+1, 7]."""
    commanded, moved = 0.05 * actions, np.diff(qpos, axis=1)
    return np.array([np.linalg.lstsq(np.stack([commanded[:, 1:, j].ravel(),
                                               commanded[:, :-1, j].ravel()], 1),
                                     moved[:, 1:, j].ravel(), rcond=None)[0] for j in range(7)])


def test_tracking_gains_match_the_original_under_random_actions(physics):
    """Per-joint least squares of dq on 0.05 a_t and 0.05 a_{t-1} under uniform random actions
    (the reference measured gains 0.61, 0.50, 0.82, 0.82, 0.86, 0.877, 0.878 and lags 0.21 and
    0.12 on joints 1 and 2, about 0 elsewhere), and the arm holds still under zero action.
    A Python loop over one jitted step (a scanned rollout compiles for minutes on a CPU)."""
    held = _rollouts_from_neutral(physics, np.zeros((1, 10, 7), np.float32))
    assert np.abs(held[0, -1] - arm_model.NEUTRAL_QPOS).max() < 2e-3  # holds against gravity
    actions = np.random.default_rng(0).uniform(-1, 1, (2, 100, 7)).astype(np.float32)
    qpos = _rollouts_from_neutral(physics, actions)
    assert np.isfinite(qpos).all()
    gains, lags = _gains_and_lags(actions, qpos).T
    assert np.abs(np.array(gains) - [0.61, 0.50, 0.82, 0.82, 0.86, 0.877, 0.878]).max() < 0.05, gains
    # joints 1 and 2 lag (torque-limited); how much depends on the sample (PyBullet itself gives
    # 0.03-0.19 and 0.12-0.29): the test below holds the lags to PyBullet's on the same actions
    assert abs(lags[0] - 0.21) < 0.1 and 0.05 < lags[1] < 0.4 and np.abs(lags[2:]).max() < 0.05, lags


def test_motor_matches_pybullet_on_the_same_actions(physics):
    """PyBullet's own arm (the original's engine; its rollouts written by
    `benchmarks/lab/arm_vs_pybullet.py --write-reference`: 4 episodes x 100 uniform random actions
    from the neutral pose) against ours under the same actions: per-joint tracking gain and lag
    to 0.01 (measured: 0.001), joint angles within 3e-3 rad over 10 steps (measured 1.5e-3) and
    2e-2 rad over 100 (measured 1.0e-2)."""
    reference = np.load(PYBULLET_ROLLOUTS)
    actions, theirs = reference["actions"], reference["qpos"]
    ours = _rollouts_from_neutral(physics, actions)
    assert np.abs(theirs[:, 0] - ours[:, 0]).max() < 1e-6  # both start at the neutral pose
    gap = np.abs(theirs - ours)
    assert gap[:, :11].max() < 3e-3 and gap.max() < 2e-2, gap.max(axis=(0, 2))
    fits = _gains_and_lags(actions, ours), _gains_and_lags(actions, theirs)
    assert np.abs(fits[0] - fits[1]).max() < 0.01, fits


def test_joint_limits_hold_with_the_motor_as_in_pybullet(physics):
    """Saturated actions (all +1, all -1, alternating; 60 steps) drive joints into their limits,
    where Bullet solves the limit and motor rows together: PyBullet's rollouts (stored by
    `benchmarks/lab/arm_vs_pybullet.py`) against ours within 0.03 rad (measured 0.011; with the
    limits left to MuJoCo's soft constraint after the motor, 0.29), every joint within 1e-3 rad
    of its range (measured 1e-4; soft limits: 0.035)."""
    reference = np.load(PYBULLET_ROLLOUTS)
    actions, theirs = reference["saturated_actions"], reference["saturated_qpos"]
    ours = _rollouts_from_neutral(physics, actions)
    low, high = physics.mj_model.jnt_range[:7].T
    assert np.all(ours > low - 1e-3) and np.all(ours < high + 1e-3)
    assert (np.abs(theirs - high) < 1e-3).sum() > 50  # the rollouts do reach the limits
    assert np.abs(theirs - ours).max() < 0.03, np.abs(theirs - ours).max(axis=(0, 1))


@functools.cache
def _table_physics():
    """The arm with its table and floor contacts: one object, so that the table tests share
    `_batched_step`'s program (it compiles for minutes on a CPU)."""
    return Physics(arm_model.load_model(), arm_model.FORCE_LIMITS)


def test_motor_holds_against_the_table_as_in_pybullet():
    """Constant actions that press the arm into the table for 60 steps (joint 2 forward, with
    joint 4 or 6; PyBullet's rollouts with the original's table and floor, stored by
    `benchmarks/lab/arm_vs_pybullet.py`) against ours with table contacts: within 0.1 rad (measured
    0.063; with the contacts unseen by the motor solve, 1.5: the table turned joint 6, which
    holds still in PyBullet, by 0.94 rad)."""
    reference = np.load(PYBULLET_ROLLOUTS)
    actions, theirs = reference["press_actions"], reference["press_qpos"]
    ours = _rollouts_from_neutral(_table_physics(), actions)
    assert theirs[0, -1, 1] - theirs[0, 0, 1] < 0.5  # the table stops joint 2 (free: 1.4 rad)
    assert np.abs(theirs - ours).max() < 0.1, np.abs(theirs - ours).max(axis=(1, 2))
    assert np.abs(ours[2, :, 5] - ours[2, 0, 5]).max() < 0.05  # joint 6 holds against the table


#: the stored table episodes replayed below: one `BATCH`
TABLE_EPISODES = 4


def test_grasp_target_departs_from_pybullet_once_the_fingers_reach_the_table():
    """PyBullet's random-action episodes with the table whose fingers reach it (stored by
    `benchmarks/lab/arm_vs_pybullet.py --parts table`: 32 of 32 drawn, first finger contact at
    steps 12-80) against ours on the same actions, the grasp target compared. Before the first
    contact the engines agree as in free motion (all 32: within 7.4 mm, most within 2 mm); in
    contact they part: after 100 steps median 3.0 cm, max 6.6 cm over the 32 (docs/fidelity.md,
    "Table contact": Bullet's and MuJoCo's friction; frictionless in both, median 0.6 cm). The
    first 4 replayed here: measured within 5.8 mm before contact and 1.9-4.2 cm (median 3.8)
    after 100 steps; the table stops our fingers where it stops PyBullet's (lowest grasp target
    within 2.0 mm, 7.4 mm in episode 0, which leaves the table's edge)."""
    reference = np.load(PYBULLET_ROLLOUTS)
    actions = reference["table_actions"][:TABLE_EPISODES]
    theirs = reference["table_grasp_target"][:TABLE_EPISODES].astype(np.float64)
    first = reference["table_first_contact"][:TABLE_EPISODES]
    qpos = _rollouts_from_neutral(_table_physics(), actions)
    model = arm_model.load_model()
    data, site = mujoco.MjData(model), model.site(arm_model.GRASP_SITE).id
    ours = np.zeros_like(theirs)
    for index in np.ndindex(qpos.shape[:2]):
        data.qpos[:] = qpos[index]
        mujoco.mj_kinematics(model, data)
        ours[index] = data.site_xpos[site]
    gap = np.linalg.norm(ours - theirs, axis=-1)
    assert np.all((first >= 0) & (first < 50)), first  # every episode reaches the table
    before = max(gap[e, :f + 1].max() for e, f in enumerate(first))
    assert before < 8e-3, before
    assert np.median(gap[:, 100]) < 0.05 and gap[:, 100].max() < 0.08, gap[:, 100]
    # the table stops the fingers in both (without it the grasp target sinks far below)
    lowest = ours[..., 2].min(1) - theirs[..., 2].min(1)
    assert np.abs(lowest).max() < 0.01, lowest


def test_motor_and_limit_rows_solve_their_complementarity_problem():
    """With `joint_range`, `motor_torque`'s net force against the reference QP of the motor and
    limit rows (`_box_qp_torque`), from states next to a limit and moving toward it; compared
    as accelerations, which the QP fixes (the split of a limited joint's force does not); no
    joint passes its limit within the substep."""
    rng = np.random.default_rng(1)
    solve = jax.jit(motor_torque, static_argnums=(6,))
    joint_range = np.stack([-np.ones(7), np.ones(7)], 1)
    for trial in range(6):
        a = rng.normal(size=(7, 7))
        mass = a @ a.T + 0.5 * np.eye(7)
        qpos = rng.uniform(0.9, 1.0, 7) * rng.choice([-1, 1], 7)
        qvel = np.sign(qpos) * rng.uniform(0, 0.5, 7)
        free_accel, target = rng.normal(0, 5, 7), qpos + 0.05 * np.sign(qpos)
        limit = rng.uniform(5, 60, 7)
        inverse = np.linalg.inv(mass)
        ref = inverse @ _box_qp_torque(mass, free_accel, qvel, qpos, target, limit, joint_range)
        ours = inverse @ np.asarray(solve(*[jnp.asarray(x, jnp.float32) for x in
                                            (mass, free_accel, qvel, qpos, target, limit)], H,
                                          joint_range=jnp.asarray(joint_range, jnp.float32)))
        assert np.abs(ours - ref).max() < 2e-2 * np.abs(ref).max(), (trial, ours, ref)
        next_q = qpos + H * (qvel + H * (free_accel + ours))
        assert np.all(np.abs(next_q) < 1.0 + 1e-4)



def test_chain_kinematics_matches_mujoco_c():
    """The arm's own forward kinematics (used instead of MJX's, see arm/kinematics.py) against
    MuJoCo C's mj_kinematics on random joint angles: every frame, COM frame, geom and site."""
    from specrl_jax.envs.arm.kinematics import ChainKinematics
    from specrl_jax.envs.zone.mjx_import import mjx

    model = arm_model.load_model()
    chain = ChainKinematics(model)
    template = mjx.make_data(mjx.put_model(model, impl="jax"))
    fill = jax.jit(jax.vmap(lambda q: chain.fill(template.replace(qpos=q))))
    rng = np.random.default_rng(3)
    qs = rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], (4, 7))
    ours = fill(jnp.asarray(qs, jnp.float32))
    data = mujoco.MjData(model)
    for i, q in enumerate(qs):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for name in ("xpos", "xquat", "xmat", "xanchor", "xaxis", "xipos", "ximat", "geom_xpos",
                     "geom_xmat", "site_xpos", "site_xmat"):
            ref = getattr(data, name).reshape(np.shape(getattr(ours, name))[1:])
            assert np.abs(np.asarray(getattr(ours, name)[i]) - ref).max() < 2e-5, name


def test_pruned_contact_pairs_cannot_touch():
    """panda.xml leaves out link 3 - table and link 4 - floor: over random joint angles within
    the limits, link 3's contact hull stays above the table top (z = 0) and link 4's above the
    floor (z = -0.4), with the bounds the model's comment derives."""
    model = arm_model.load_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(4)
    lowest = {"link3": np.inf, "link4": np.inf}
    for q in rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], (3000, 7)):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for name in lowest:
            g = model.geom(name)
            adr, num = model.mesh_vertadr[g.dataid[0]], model.mesh_vertnum[g.dataid[0]]
            verts = model.mesh_vert[adr:adr + num] @ data.geom_xmat[g.id].reshape(3, 3).T
            lowest[name] = min(lowest[name], (verts[:, 2] + data.geom_xpos[g.id][2]).min())
    assert lowest["link3"] > 0.0365 - 1e-6 and lowest["link4"] > -0.21 - 1e-6, lowest
    pairs = {frozenset((model.geom(a).name, model.geom(b).name))
             for a, b in zip(model.pair_geom1, model.pair_geom2)}
    assert {"link3", "table"} not in pairs and {"link4", "floor"} not in pairs
    assert {"link4", "table"} in pairs and {"link5", "floor"} in pairs and len(pairs) == 13


def test_spd_inverse_equals_the_library_inverse():
    from specrl_jax.envs.arm.physics import spd_inverse

    rng = np.random.default_rng(6)
    a = rng.normal(size=(3, 7, 7))
    mass = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(7)
    ours = np.asarray(jax.jit(jax.vmap(spd_inverse))(jnp.asarray(mass, jnp.float32)))
    np.testing.assert_allclose(ours @ mass, np.broadcast_to(np.eye(7), (3, 7, 7)), atol=2e-3)


def test_batched_collision_gives_mjx_contacts():
    """`arm/collision.py` (each kind of pair in one padded call) against `mjx.collision` on
    random joint angles, many pressing links into the table: the same contacts and parameters in
    the same order, to float rounding (those within 1 cm; farther ones never act). Where a clipped face has only 3 distinct points, the
    4th contact repeats one of them, and which one rests on a float tie: compared as point sets."""
    from specrl_jax.envs.zone.mjx_import import mjx

    model = _contact_model()
    physics = Physics(model, arm_model.FORCE_LIMITS)
    m = physics.model
    rng = np.random.default_rng(7)
    qs = jnp.asarray(rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], (48, 7)), jnp.float32)

    def contacts(collide):
        def one(q):
            data = mjx.com_pos(m, physics.kinematics.fill(physics._template.replace(qpos=q)))
            return collide(m, data)._impl.contact
        return jax.jit(jax.vmap(one))(qs)

    ref, ours = contacts(mjx.collision), contacts(physics.collision.collide)
    for name in ("geom", "friction", "solref", "solimp", "includemargin", "dim"):
        assert np.array_equal(np.asarray(getattr(ref, name)), np.asarray(getattr(ours, name))), name
    np.testing.assert_allclose(np.asarray(ours.frame), np.asarray(ref.frame), atol=1e-5)
    per_pair = lambda x, k: np.asarray(x).reshape(len(qs), -1, 4, *np.shape(x)[2:])
    dist_r, dist_o = per_pair(ref.dist, 1), per_pair(ours.dist, 1)
    pos_r, pos_o = per_pair(ref.pos, 3), per_pair(ours.pos, 3)
    for a_dist, a_pos, b_dist, b_pos in ((dist_o, pos_o, dist_r, pos_r),
                                         (dist_r, pos_r, dist_o, pos_o)):
        # every contact of one has a twin in the other's contacts of the same pair
        gap = np.linalg.norm(a_pos[:, :, :, None] - b_pos[:, :, None], axis=-1)
        twin = (gap < 1e-4) & (np.abs(a_dist[..., None] - b_dist[:, :, None]) < 1e-5)
        assert (twin.any(-1) | (a_dist > 0.01)).all()  # the contacts that can act
    assert (dist_r < 0).any(-1).sum() >= 10  # pairs in contact were compared
