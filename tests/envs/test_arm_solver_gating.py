"""The arm runs MuJoCo's collision and constraint solver only where a constraint row can act:
`ContactReach`'s bounds against MuJoCo C's distances, and the gathered physics step against the
step that solves every arm."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm.env import ACTION_SCALE
from specrl_jax.envs.arm.physics import Physics, PhysicsState

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
    probe = jax.jit(jax.vmap(lambda q: (reach.gaps(physics.data(physics.init(q))),
                                        physics._needs_solver(physics.data(physics.init(q))))))
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
    and 20 free: gathering them into 16 slots (capacities 0.25 and 0.5), or with 10 slots
    (capacity 0.3) solving every arm while more than 10 need it and gathering after, lands where the step that runs MuJoCo's solver on every arm does, to float
    rounding (free arms take MuJoCo's unconstrained acceleration exactly, the solver's to its
    tolerance)."""
    model = arm_model.load_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    low, high = model.jnt_range[:, 0], model.jnt_range[:, 1]
    touching, free = [], []
    while len(touching) < 12 or len(free) < 20:
        data.qpos[:] = rng.uniform(low, high)
        mujoco.mj_forward(model, data)
        depth = data.contact.dist[:data.ncon].min() if data.ncon else np.inf
        if -0.01 < depth < 0 and len(touching) < 12:
            touching.append(data.qpos.copy())
        elif depth > 0.05 and len(free) < 20:
            free.append(data.qpos.copy())
    qpos = jnp.asarray(np.concatenate([touching, free]), jnp.float32)
    zeros = jnp.zeros_like(qpos)
    qvel = jnp.asarray(rng.uniform(-1, 1, qpos.shape), jnp.float32)
    state = PhysicsState(qpos=qpos, qvel=qvel, qacc_warmstart=zeros, qfrc_constraint=zeros)
    action = jnp.asarray(rng.uniform(-1, 1, qpos.shape), jnp.float32)
    after = {}
    for capacity in (None, (0.25, 0.5), (0.3,)):
        physics = Physics(model, arm_model.FORCE_LIMITS, solve_capacities=capacity)
        step = jax.jit(jax.vmap(lambda s, a: physics.step(s, s.qpos + ACTION_SCALE * a)))
        after[capacity] = step(state, action)
    for capacity in ((0.25, 0.5), (0.3,)):
        np.testing.assert_allclose(after[capacity].qpos, after[None].qpos, atol=2e-6)
        np.testing.assert_allclose(after[capacity].qvel, after[None].qvel, atol=5e-4)
    moved = np.abs(np.asarray(after[None].qfrc_constraint[:12])).max(1)
    assert (moved > 0).sum() >= 4  # the table still pushes on touching arms at the end
