"""The arm's physics in MJX: PyBullet's position motor emulated on joint targets.

PyBullet's POSITION_CONTROL (the original's) is a velocity-level motor constraint: every physics
substep it asks for joint velocity `v* = 50 (q_target - q)` (position gain 0.1 over h = 1/500 s),
with the impulse of each joint limited to `force_limit * h`, and solves all joints together with
the joint-limit constraints, which let a joint move at most to its limit within the substep. Here
each substep takes MuJoCo's smooth dynamics plus the contact forces of the previous substep,
finds the joint forces of the motor and limit rows together (projected Gauss-Seidel in the
inverse mass matrix, as Bullet's sequential-impulse solver), applies them, then lets MuJoCo solve
the table/floor contacts and integrate (semi-implicit Euler, as Bullet). Bullet solves the motor
and contact rows in one problem; counting the last substep's contact forces in the motor solve
is one Gauss-Seidel pass between the two, lagged by a substep, so that a motor holds against a
contact as it does in Bullet. MuJoCo's own soft joint limits stay in the model as a backstop;
they act only where a contact pushes a joint past its limit. MuJoCo's collision and solver,
most of a substep's cost, run only for the arms whose hulls come within reach of the table or
floor or whose joints pass a limit, and the collision and solve only over the contact pairs within
that reach (`Physics` says how).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from specrl_jax.envs import compiled
from specrl_jax.envs.arm.collision import Collision, ContactReach
from specrl_jax.envs.arm.config import MOTOR_SOLVES
from specrl_jax.envs.arm.kinematics import ChainKinematics
from specrl_jax.envs.compaction import where_needed
from specrl_jax.envs.zone import small_linalg
from specrl_jax.envs.zone.mjx_import import mjx

SUBSTEPS = 20
#: PyBullet's default position gain over its timestep: v* = kp (q_t - q) / h
MOTOR_RATE = 0.1 / 0.002
#: projected Gauss-Seidel sweeps over the 7 motor rows per substep
PGS_SWEEPS = 16
#: the sub-batch sizes, as shares of a batch, whose collision and constraint solve run gathered
SOLVE_CAPACITIES = (0.125, 0.25)
#: how far beyond a contact's margin an arm's distance bound still runs the solver, m
REACH_SLACK = 1e-3
#: the contact pairs (of 13) an arm's collision and solve take: those of least distance bound;
#: an arm with more pairs within reach runs them over every pair
SOLVE_PAIRS = 2
#: the sub-batch size, as a share of the batch, of the arms with more pairs within reach
OVERFLOW_CAPACITY = 1 / 64


@struct.dataclass
class PhysicsState:
    """What one arm carries between env steps.

    Attributes:
        qpos: float32[7] joint angles, rad.
        qvel: float32[7] joint velocities, rad/s.
        qacc_warmstart: float32[7] MuJoCo's constraint-solver warm start.
        qfrc_constraint: float32[7] the joint forces of the last substep's contacts (and
            MuJoCo's limit backstop), N m, which the next substep's motor solve sees.
    """

    qpos: jax.Array
    qvel: jax.Array
    qacc_warmstart: jax.Array
    qfrc_constraint: jax.Array


def spd_inverse(mass: jax.Array) -> jax.Array:
    """float[N, N]: the inverse of a small symmetric positive definite matrix, through a
    Cholesky factor written out as arithmetic (`zone/small_linalg.py`): under `vmap` on a GPU it
    fuses with its neighbours, where a library call would not."""
    factor = small_linalg.cho_factor(mass, lower=True)
    return small_linalg.cho_solve(factor, jnp.eye(mass.shape[-1], dtype=mass.dtype))


def motor_torque(mass: jax.Array, free_accel: jax.Array, qvel: jax.Array, qpos: jax.Array,
                 target: jax.Array, force_limit: jax.Array, h: float,
                 sweeps: int = PGS_SWEEPS, inverse: jax.Array | None = None,
                 joint_range: jax.Array | None = None, solve: str = "xla") -> jax.Array:
    """Joint forces of PyBullet's velocity-level motor, and of its joint limits when
    `joint_range` is given, float32[N] (N m).

    Args:
        mass: float[N, N] joint-space mass matrix.
        free_accel: float[N] acceleration without the motor (gravity, Coriolis), rad/s^2.
        qvel, qpos, target: float[N] joint velocity, angle and target angle.
        force_limit: float[N] per-joint motor torque bound, N m.
        h: the substep, s.
        inverse: float[N, N] the inverse of `mass`, if the caller has it.
        joint_range: float[N, 2] lower and upper joint limits, rad (None: unlimited).
        solve: how the Gauss-Seidel sweeps run (`MOTOR_SOLVES`): "xla" as jnp operations,
            "pallas" as one Pallas kernel per arm (a GPU), "pallas_interpret" that kernel in
            Pallas' interpreter (tests on a CPU), "auto" the kernel on a GPU and jnp
            operations elsewhere. The same arithmetic.

    Returns the motor torques `tau`, `|tau_i| <= force_limit_i`, such that each unsaturated joint
    reaches `v* = MOTOR_RATE (target - q)` after the substep (given the saturated ones), plus the
    limit forces (a joint's lower limit pushes up, its upper limit down, each only as much as
    keeps `q + h v` within the range; beyond it, back to it in one substep).
    """
    if solve not in MOTOR_SOLVES:
        raise ValueError(f"solve={solve!r}; choose one of {', '.join(MOTOR_SOLVES)}")
    if solve == "auto":
        solve = "pallas" if jax.default_backend() == "gpu" else "xla"
    inverse = spd_inverse(mass) if inverse is None else inverse
    speed_to_accel = lambda speed: (speed - qvel) / h - free_accel  # extra acceleration needed
    want = speed_to_accel(MOTOR_RATE * (target - qpos))
    num = want.shape[0]
    if joint_range is None:  # an infinite range: the limit rows never act
        joint_range = jnp.stack([jnp.full(num, -jnp.inf), jnp.full(num, jnp.inf)], axis=1)
    top = speed_to_accel((joint_range[:, 1] - qpos) / h)
    bottom = speed_to_accel((joint_range[:, 0] - qpos) / h)
    start = jnp.clip(mass @ want, -force_limit, force_limit)
    rows = tuple(jnp.asarray(row, want.dtype) for row in (want, top, bottom, force_limit, start))
    inverse = jnp.asarray(inverse, want.dtype)
    if solve == "xla":
        scalars = lambda v: [v[i] for i in range(num)]
        inv = [scalars(row) for row in scalars(inverse)]
        tau, down, up = _gauss_seidel(inv, *map(scalars, rows), sweeps)
        return jnp.stack(tau) + jnp.stack(down) + jnp.stack(up)
    return _gauss_seidel_kernel(inverse, *rows, sweeps, interpret=solve == "pallas_interpret")


def _gauss_seidel(inv: list, want: list, top: list, bottom: list, limit: list, start: list,
                  sweeps: int) -> tuple[tuple, ...]:
    """(motor, upper-limit, lower-limit) forces, N scalars each, after `sweeps` projected
    Gauss-Seidel sweeps from the motor torques `start`: `motor_torque`'s rows as lists of
    scalars (`inv` the inverse mass matrix's N x N).

    The sweeps work on scalars (one per joint), not on vectors updated in place: under `vmap`
    every operation is then elementwise over the batch and fuses with its neighbours, where
    in-place row updates and row products launch a scatter and a reduction per row."""
    rows = range(len(start))

    def accel(i: int, force: list) -> jax.Array:  # row i of inverse @ force
        total = inv[i][0] * force[0]
        for j in rows[1:]:
            total = total + inv[i][j] * force[j]
        return total

    def sweep(_, carry):
        tau, down, up = (list(part) for part in carry)  # motor, upper-limit <= 0, lower-limit >= 0
        net = [tau[j] + down[j] + up[j] for j in rows]
        for i in rows:  # rows in order, as Bullet's sequential impulses
            residual = want[i] - accel(i, net)
            tau[i] = jnp.clip(tau[i] + residual / inv[i][i], -limit[i], limit[i])
            net[i] = tau[i] + down[i] + up[i]
        for i in rows:
            a = accel(i, net)
            new_down = jnp.minimum(down[i] + (top[i] - a) / inv[i][i], 0.0)
            a = a + (new_down - down[i]) * inv[i][i]
            down[i] = new_down
            up[i] = jnp.maximum(up[i] + (bottom[i] - a) / inv[i][i], 0.0)
            net[i] = tau[i] + down[i] + up[i]
        return tuple(tau), tuple(down), tuple(up)

    zeros = (jnp.zeros((), inv[0][0].dtype),) * len(rows)
    return jax.lax.fori_loop(0, sweeps, sweep, (tuple(start), zeros, zeros))


def _gauss_seidel_kernel(inverse, want, top, bottom, limit, start, sweeps: int,
                         interpret: bool) -> jax.Array:
    """`_gauss_seidel` as one Pallas (Triton) kernel per arm: the arm's rows packed in a table
    of a power-of-two length, read as scalars, every sweep in the kernel's registers."""
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton

    num = start.shape[0]
    table = jnp.concatenate([inverse.reshape(-1), want, top, bottom, limit, start])
    size = 1 << int(np.ceil(np.log2(table.shape[0])))  # Triton blocks are powers of two
    table = jnp.pad(table, (0, size - table.shape[0]))
    width = 1 << int(np.ceil(np.log2(num)))

    def kernel(table_ref, out_ref):
        read = lambda offset: [table_ref[offset + i] for i in range(num)]
        inv = [read(i * num) for i in range(num)]
        base = num * num
        rows = (read(base + k * num) for k in range(5))  # want, top, bottom, limit, start
        tau, down, up = _gauss_seidel(inv, *rows, sweeps)
        lanes = jax.lax.broadcasted_iota(jnp.int32, (width,), 0)
        out = jnp.zeros((width,), table_ref.dtype)
        for i in range(num):
            out = jnp.where(lanes == i, tau[i] + down[i] + up[i], out)
        out_ref[...] = out

    out = pl.pallas_call(
        kernel,
        out_shape=jax.ShapeDtypeStruct((width,), table.dtype),
        # no grid of its own: `vmap` makes the arms the grid, the last (x) axis taking the
        # innermost batch, which may exceed CUDA's 65,535 on the y and z axes
        interpret=interpret,
        compiler_params=None if interpret else triton.CompilerParams(num_warps=1, num_stages=1),
    )(table)
    return out[:num]


class Physics:
    """Steps the arm model: `init(qpos)` and `step(state, target)` for one arm (vmappable).

    MuJoCo's collision and constraint solver run only for arms that may touch the table or
    floor or pass a joint limit in the substep (`ContactReach`); the others need no constraint
    force, and take the unconstrained acceleration. Under `vmap` those arms are gathered into
    the smallest sub-batch of `solve_capacities` times the batch that holds them
    (`compaction.where_needed`; the largest in turn when more need it).
    `solve_capacities=None` runs the collision and solver on every arm, as `mjx.forward`. The
    collision and solve take the `solve_pairs` contact pairs of least distance bound (the others
    are beyond their margin, their rows zero); the arms with more pairs within reach are
    gathered apart (a share `OVERFLOW_CAPACITY` of the batch at a time) and run over every pair
    (`solve_pairs=None`: every arm over every pair). `motor_solve`: how the motor solve runs
    (`motor_torque`'s `solve`).
    """

    def __init__(self, model: mujoco.MjModel, force_limit: np.ndarray, substeps: int = SUBSTEPS,
                 solve_capacities: tuple[float, ...] | None = SOLVE_CAPACITIES,
                 solve_pairs: int | None = SOLVE_PAIRS, motor_solve: str = "auto"):
        self.motor_solve = motor_solve  # checked where it runs (`motor_torque`) and by ArmConfig
        self.mj_model = model
        self._digest = compiled.model_digest(model)
        self.model = mjx.put_model(model, impl="jax")
        self.substeps = substeps
        self.force_limit = np.asarray(force_limit, np.float32)
        arm = slice(0, len(self.force_limit))
        self.joint_range = np.where(model.jnt_limited[arm, None], model.jnt_range[arm],
                                    [-np.inf, np.inf]).astype(np.float32)
        self._template = mjx.make_data(self.model)
        self.kinematics = ChainKinematics(model)
        self.collision = Collision(model, self.model)
        self._has_constraints = self._template._impl.efc_J.size > 0
        self._reach = ContactReach(model, self.model, REACH_SLACK)
        if solve_pairs is not None and solve_pairs < 1:
            raise ValueError(f"solve_pairs is a count of contact pairs (>= 1) or None (all); got "
                             f"{solve_pairs}")
        if solve_pairs is not None and solve_pairs >= model.npair:
            solve_pairs = None  # every pair: the plain collision
        if solve_pairs is not None and not self.collision.supports_pairs:
            raise ValueError("solve_pairs needs primitive-mesh contact pairs with one contact "
                             "count each; pass solve_pairs=None")
        self.solve_pairs = solve_pairs
        self.solve_capacities = solve_capacities
        every_pair = self._solve_every_pair
        if solve_pairs is None:
            self._solve = every_pair if solve_capacities is None else where_needed(
                every_pair, self._needs_solver, self._unconstrained, solve_capacities)
        else:
            near = self._solve_nearest_pairs if solve_capacities is None else where_needed(
                self._solve_nearest_pairs, self._needs_nearest_pairs, self._unconstrained,
                solve_capacities)
            # per arm (x, its nearest-pairs result): every pair's result instead where needed
            overflow = where_needed(lambda pair: every_pair(pair[0]),
                                    lambda pair: self._too_many_pairs(pair[0]),
                                    lambda pair: pair[1], (OVERFLOW_CAPACITY,))
            self._solve = lambda x: overflow((x, near(x)))

    def init(self, qpos: jax.Array) -> PhysicsState:
        zeros = jnp.zeros(self.mj_model.nv, jnp.float32)
        return PhysicsState(qpos=jnp.asarray(qpos, jnp.float32), qvel=zeros, qacc_warmstart=zeros,
                            qfrc_constraint=zeros)

    def data(self, state: PhysicsState) -> mjx.Data:
        """MJX data with the kinematics (body, joint, geom and site frames) at `state`."""
        data = self._template.replace(qpos=state.qpos, qvel=state.qvel)
        return self.kinematics.fill(data)

    def position_stage(self, data: mjx.Data) -> mjx.Data:
        """`mjx.fwd_position` without the collision and constraints (`solved` has them),
        with the chain's own kinematics (ChainKinematics says why); the stages this model lacks
        (cameras, lights, tendons) are left out."""
        m = self.model
        data = mjx.com_pos(m, self.kinematics.fill(data))
        return mjx.transmission(m, mjx.factor_m(m, mjx.crb(m, data)))

    def solved(self, data: mjx.Data) -> mjx.Data:
        """`data` (after `accelerate`) with MuJoCo's contacts, constraint rows and solve."""
        return self._rows_solved(self.collision.collide(self.model, data))

    def _rows_solved(self, data: mjx.Data) -> mjx.Data:
        m = self.model
        # `where_needed` may trace this after `step`'s own context has closed (under an outer vmap)
        with small_linalg.small_cholesky():
            return mjx.solve(m, mjx.make_constraint(m, data))

    # The constraint paths take `(data after accelerate, ContactReach gaps float[P])` and give
    # (qacc, qfrc_constraint), both float[7].
    def _constrain(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        return self._solve((data, self._reach.gaps(data)))

    def _solve_every_pair(self, x: tuple) -> tuple[jax.Array, jax.Array]:
        data = self._rows_solved(self.collision.collide(self.model, x[0]))
        return data.qacc, data.qfrc_constraint

    def _solve_nearest_pairs(self, x: tuple) -> tuple[jax.Array, jax.Array]:
        data, gaps = x
        pairs = jax.lax.top_k(-gaps, self.solve_pairs)[1]
        data = self._rows_solved(self.collision.collide_pairs(self.model, data, pairs))
        return data.qacc, data.qfrc_constraint

    def _pairs_in_reach(self, x: tuple) -> jax.Array:
        return jnp.sum(x[1] < self._reach.reach)

    def _too_many_pairs(self, x: tuple) -> jax.Array:
        return self._pairs_in_reach(x) > self.solve_pairs

    def _needs_solver(self, x: tuple) -> jax.Array:
        return (self._pairs_in_reach(x) > 0) | self._reach.past_limit(x[0].qpos)

    def _needs_nearest_pairs(self, x: tuple) -> jax.Array:
        return self._needs_solver(x) & ~self._too_many_pairs(x)

    @staticmethod
    def _unconstrained(x: tuple) -> tuple[jax.Array, jax.Array]:
        qacc = x[0].qacc_smooth
        return qacc, jnp.zeros_like(qacc)

    def accelerate(self, data: mjx.Data, target: jax.Array,
                   qfrc_constraint: jax.Array) -> mjx.Data:
        """`data` at a substep's start with the motor torques toward joint targets `target`
        ([7], rad) applied and the unconstrained acceleration `qacc_smooth`. `qfrc_constraint`
        ([7], N m): the previous substep's constraint forces, which the motor solve counts as
        known (Bullet solves motor and contact rows together; this lags the contacts by one
        substep)."""
        m = self.model
        data = mjx.fwd_velocity(m, self.position_stage(data))
        mass = mjx.full_m(m, data)
        inverse = spd_inverse(mass)
        free_accel = inverse @ (data.qfrc_passive - data.qfrc_bias + qfrc_constraint)
        h = float(self.mj_model.opt.timestep)
        tau = motor_torque(mass, free_accel, data.qvel, data.qpos, target,
                           jnp.asarray(self.force_limit), h, inverse=inverse,
                           joint_range=jnp.asarray(self.joint_range), solve=self.motor_solve)
        return mjx.fwd_acceleration(m, mjx.fwd_actuation(m, data.replace(qfrc_applied=tau)))

    def substep(self, data: mjx.Data, target: jax.Array, qfrc_constraint: jax.Array) -> mjx.Data:
        """One physics step of h = model timestep toward joint targets `target` ([7], rad),
        after the previous substep's constraint forces `qfrc_constraint` ([7], N m)."""
        data = self.accelerate(data, target, qfrc_constraint)
        qacc, qfrc = (self._constrain(data) if self._has_constraints
                      else self._unconstrained((data, None)))
        return mjx.euler(self.model, data.replace(qacc=qacc, qfrc_constraint=qfrc))

    def step(self, state: PhysicsState, target: jax.Array) -> PhysicsState:
        """`substeps` physics steps toward `target` (float[7], rad), held through the step.

        Traced once per model and options in a process (`compiled.ByKey`): other envs of the
        same arm model reuse it.
        """
        return _shared_step(compiled.ByKey(self._trace_key(), self), state, target)

    def _trace_key(self) -> tuple:
        """All that a trace of `step` reads besides its arguments."""
        return (self._digest, self.force_limit.tobytes(), self.substeps, self.solve_capacities,
                self.solve_pairs, self.motor_solve)

    def _step_traced(self, state: PhysicsState, target: jax.Array) -> PhysicsState:
        def substep(_, carry: PhysicsState) -> PhysicsState:
            # a substep depends on these four only: the loop carries them, not all of mjx.Data
            data = self._template.replace(
                qpos=carry.qpos, qvel=carry.qvel, qacc_warmstart=carry.qacc_warmstart)
            data = self.substep(data, target, carry.qfrc_constraint)
            return PhysicsState(qpos=data.qpos, qvel=data.qvel, qacc_warmstart=data.qacc_warmstart,
                                qfrc_constraint=data.qfrc_constraint)

        # MJX's own Cholesky factorisations (mass matrix, Newton Hessian), written out too
        with small_linalg.small_cholesky():
            return jax.lax.fori_loop(0, self.substeps, substep, state)


@functools.partial(jax.jit, static_argnums=0)
def _shared_step(
    physics: compiled.ByKey[Physics], state: PhysicsState, target: jax.Array
) -> PhysicsState:
    return physics.value._step_traced(state, target)


__all__ = ["MOTOR_RATE", "MOTOR_SOLVES", "SUBSTEPS", "Physics", "PhysicsState", "motor_torque",
           "spd_inverse"]
