"""The arm runs MuJoCo's collision and constraint solver only where a constraint row can act:
`ContactReach`'s bounds against MuJoCo C's distances, and the gathered physics step against the
step that solves every arm."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.collision import keep_contacts
from specrl_jax.envs.arm.env import ACTION_SCALE
from specrl_jax.envs.arm.physics import Physics, PhysicsState
from specrl_jax.envs.zone import small_linalg

DISTMAX = 0.5


def test_contact_reach_bounds_the_distance_of_every_pair():
    """Over random joint angles within the limits: each pair's bound is at most MuJoCo C's
    `mj_geomDistance` between the same hull and the table or floor (and for most pairs within
    5 cm, within 1e-5 m of it: tight), so no arm that touches skips the solver."""
    model = arm_model.load_model()
    physics = Physics(model, arm_model.FORCE_LIMITS)
    reach = physics._reach
    rng = np.random.default_rng(0)
    qs = rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], (300, 7)).astype(np.float32)
    def probe(q):
        data = physics.data(physics.init(q))
        gaps = reach.gaps(data)
        return gaps, physics._needs_solver((data, gaps))

    probe = jax.jit(jax.vmap(probe))
    gaps, needs = map(np.asarray, probe(jnp.asarray(qs)))
    data = mujoco.MjData(model)
    distance = np.zeros_like(gaps)
    for i, q in enumerate(qs):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for j, (first, second) in enumerate(zip(reach.other_geom, reach.mesh_geom)):
            distance[i, j] = mujoco.mj_geomDistance(model, data, first, second, DISTMAX, None)
    near = distance < DISTMAX
    assert (gaps[near] <= distance[near] + 1e-6).all()
    close = np.abs(gaps - distance)[distance < 0.05]  # beside a box edge the bound is less
    assert close.size >= 50 and np.quantile(close, 0.9) < 1e-5
    touching = (distance < 0).any(1)
    assert touching.sum() >= 10 and (needs >= touching).all()
    # and MJX's own activation: a contact row acts where dist < includemargin
    m = physics.model

    def active(q):
        data = physics.data(physics.init(q))
        contact = physics.collision.collide(m, data)._impl.contact
        return jnp.any(contact.dist < contact.includemargin)

    mjx_active = np.asarray(jax.jit(jax.vmap(active))(jnp.asarray(qs)))
    assert mjx_active.sum() >= 10 and (needs >= mjx_active).all()
    assert 10 <= (~needs).sum()  # the test also saw arms that skip the solver
    assert (needs & ~touching).sum() <= 0.1 * len(qs)


def test_gathered_step_matches_the_step_that_solves_every_arm():
    """One env step of 32 arms, 12 starting on the table or floor (a link up to 1 cm deep)
    and 20 free, gathered into 10 slots (capacity 0.3; 10 at a time in turn while more than 10
    need it; test_compaction checks the choice of sub-batch size), lands where the step that
    runs MuJoCo's solver on every arm does, to float rounding (free arms take MuJoCo's
    unconstrained acceleration exactly, the solver's to its tolerance)."""
    model = arm_model.load_model()
    state, action = _touching_and_free(model, 12, 20)
    after = {}
    for capacity in (None, (0.3,)):
        physics = Physics(model, arm_model.FORCE_LIMITS, solve_capacities=capacity,
                          solve_pairs=None)  # the next test checks the nearest pairs
        step = jax.jit(jax.vmap(lambda s, a, physics=physics: physics.step(s, s.qpos + ACTION_SCALE * a)))
        after[capacity] = step(state, action)
    np.testing.assert_allclose(after[(0.3,)].qpos, after[None].qpos, atol=2e-6)
    np.testing.assert_allclose(after[(0.3,)].qvel, after[None].qvel, atol=5e-4)
    moved = np.abs(np.asarray(after[None].qfrc_constraint[:12])).max(1)
    assert (moved > 0).sum() >= 4  # the table still pushes on touching arms at the end


def test_solve_over_the_nearest_pairs_matches_the_solve_over_all():
    """One substep's constraint solve of 16 arms on the table (1 or 2 contact pairs within
    reach, 1 to 8 active contacts) and 4 free. The contacts `collide_pairs` computes for an
    arm's 2 pairs of least distance bound are MuJoCo's (MJX's collision), and the solve over
    their rows alone gives the accelerations and constraint forces of the solve over all 13
    pairs to float rounding (1e-4 of the largest acceleration: the rows it drops are zero), but
    for at most two arms where the programs' rounding repeats another corner of a pair. With
    room for one pair, the arms with two take the solve over every pair (and one pair alone
    would be wrong for them)."""
    model = arm_model.load_model()
    state, action = _touching_and_free(model, 16, 4, seed=4)
    physics = {k: Physics(model, arm_model.FORCE_LIMITS, solve_capacities=None, solve_pairs=k)
               for k in (None, 2, 1)}
    reference = physics[None]
    collision, m = reference.collision, reference.model

    def solves(s, a):
        data = reference.data(s).replace(qacc_warmstart=s.qacc_warmstart)
        data = reference.accelerate(data, s.qpos + ACTION_SCALE * a, s.qfrc_constraint)
        x = (data, reference._reach.gaps(data))
        pairs = jax.lax.top_k(-x[1], 2)[1]
        collided = collision.collide(m, data)
        kept = keep_contacts(collided, jnp.asarray(collision.pair_rows)[pairs].reshape(-1))
        solved = reference._rows_solved(collided)
        contact = collided._impl.contact
        return {"all": (solved.qacc, solved.qfrc_constraint),
                "2 pairs": physics[2]._solve_nearest_pairs(x),
                "1": physics[1]._solve(x), "1 alone": physics[1]._solve_nearest_pairs(x),
                "in reach": reference._pairs_in_reach(x),
                "active": jnp.sum(contact.dist < contact.includemargin),
                "kept": kept._impl.contact,
                "computed": collision.collide_pairs(m, data, pairs)._impl.contact}

    with small_linalg.small_cholesky():
        out = jax.jit(jax.vmap(solves))(state, action)
    active, in_reach = np.asarray(out["active"]), np.asarray(out["in reach"])
    assert (active[:16] >= 1).all() and (active[16:] == 0).all()
    assert (active == 8).sum() >= 2 and (in_reach == 2).sum() >= 2 and (in_reach == 1).sum() >= 2
    for field in ("dist", "pos"):  # MJX repeats one corner to fill a pair's 4 contacts: which one
        # can differ with rounding between programs, so compare the distinct contacts
        for kept, computed in zip(np.asarray(getattr(out["kept"], field)),
                                  np.asarray(getattr(out["computed"], field))):
            kept, computed = kept.reshape(2, 4, -1), computed.reshape(2, 4, -1)
            gap = np.abs(kept[:, :, None] - computed[:, None]).max(-1)  # [pair, kept, computed]
            assert gap.min(2).max() < 1e-5 and gap.min(1).max() < 1e-5, field
    qacc, qfrc = map(np.asarray, out["all"])
    assert np.abs(qfrc[:16]).max() > 1.0  # the contacts push
    scale = np.abs(qacc).max(1, keepdims=True)
    # MJX fills a pair's 4 contact slots by repeating a corner, and which one can differ with
    # rounding between two programs (and CPUs): the repeat then weighs twice in another place, a
    # different, equally valid problem (about 1e-2 of the accelerations apart). So at most two arms
    # may be that far off; every other arm agrees to float rounding
    def agree(got, want, arms):
        off = np.maximum(np.abs(np.asarray(got) - want).max(1) - 1e-6, 0)[arms] / scale[arms, 0]
        return (off > 1e-4).sum() <= 2 and off.max(initial=0.0) < 2e-2

    for got, want in zip(out["2 pairs"], (qacc, qfrc)):
        assert agree(got, want, np.ones(len(qacc), bool))
    for got, want in zip(out["1"], (qacc, qfrc)):  # those with 2 pairs: the solve over every pair
        assert agree(got, want, in_reach > 1)
    wrong = np.abs(np.asarray(out["1 alone"][0]) - qacc).max(1)
    assert wrong[in_reach > 1].max() > 0.1 * scale.max()
    with pytest.raises(ValueError, match="solve_pairs is a count of contact pairs"):
        Physics(model, arm_model.FORCE_LIMITS, solve_pairs=0)
    assert Physics(model, arm_model.FORCE_LIMITS, solve_pairs=model.npair).solve_pairs is None


def _touching_and_free(model: mujoco.MjModel, touching: int, free: int, seed: int = 3
                       ) -> tuple[PhysicsState, jax.Array]:
    """Arm states (random joint angles within the limits and velocities in [-1, 1]) with
    `touching` arms on the table or floor (a link up to 1 cm deep) then `free` arms at least
    5 cm clear, and uniform random actions."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]
    on, off = [], []
    while len(on) < touching or len(off) < free:
        data.qpos[:] = rng.uniform(low, high)
        mujoco.mj_forward(model, data)
        depth = data.contact.dist[:data.ncon].min() if data.ncon else np.inf
        if -0.01 < depth < 0 and len(on) < touching:
            on.append(data.qpos.copy())
        elif depth > 0.05 and len(off) < free:
            off.append(data.qpos.copy())
    qpos = jnp.asarray(np.concatenate([on, off]), jnp.float32)
    zeros = jnp.zeros_like(qpos)
    qvel = jnp.asarray(rng.uniform(-1, 1, qpos.shape), jnp.float32)
    state = PhysicsState(qpos=qpos, qvel=qvel, qacc_warmstart=zeros, qfrc_constraint=zeros)
    return state, jnp.asarray(rng.uniform(-1, 1, qpos.shape), jnp.float32)
