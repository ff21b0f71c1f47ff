"""MuJoCo's Newton constraint solve (`mjx.solve`) as a loop of fixed trip count.

`mjx.solve` repeats its Newton step in a `lax.while_loop` until the step stops improving. Under
`vmap` that loop runs while any item of the batch goes on, every item taking the step and keeping
the result only while its own test holds, and on a GPU the loop hands its condition back to the
host after every step. `solve` here runs the model's `opt.iterations` steps with that same per-item
keep: the same results, and a loop XLA knows the length of, with no round trip to the host.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco.mjx._src import math as mjx_math
from mujoco.mjx._src import solver as mjx_solver
from mujoco.mjx._src.types import DisableBit, SolverType

from specrl_jax.envs.zone.mjx_import import mjx


def _goes_on(m: mjx.Model, d: mjx.Data, ctx: mjx_solver.Context) -> jax.Array:
    """bool: whether MuJoCo's stopping test lets `ctx` take another Newton step."""
    improvement = mjx_solver._rescale(m, d, ctx.prev_cost - ctx.cost)
    gradient = mjx_solver._rescale(m, d, mjx_math.norm(ctx.grad))
    stop = ((ctx.solver_niter >= m.opt.iterations) | (improvement < m.opt.tolerance)
            | (gradient < m.opt.tolerance))
    return ~stop


def _newton_step(m: mjx.Model, d: mjx.Data, ctx: mjx_solver.Context) -> mjx_solver.Context:
    ctx = mjx_solver._linesearch(m, d, ctx)
    ctx = mjx_solver._update_constraint(m, d, ctx)
    ctx = mjx_solver._update_gradient(m, d, ctx)
    return ctx.replace(search=-ctx.Mgrad, solver_niter=ctx.solver_niter + 1)


def solve(m: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mjx.solve(m, d)` for a model with MuJoCo's Newton solver: `d` (after
    `mjx.make_constraint`) with `qacc`, `qfrc_constraint` and the constraint forces solved, and
    the Newton steps taken in `solver_niter` (which `mjx.solve` leaves alone)."""
    if m.opt.solver != SolverType.NEWTON:
        raise ValueError(f"the fixed-count solve is MuJoCo's Newton solver; the model has "
                         f"{SolverType(m.opt.solver).name}")
    qacc = d.qacc_smooth
    if not m.opt.disableflags & DisableBit.WARMSTART:
        warm = mjx_solver.Context.create(m, d.replace(qacc=d.qacc_warmstart), grad=False)
        smooth = mjx_solver.Context.create(m, d.replace(qacc=d.qacc_smooth), grad=False)
        qacc = jnp.where(warm.cost < smooth.cost, d.qacc_warmstart, d.qacc_smooth)
    d = d.replace(qacc=qacc)

    def iteration(_, ctx):
        going = _goes_on(m, d, ctx)
        stepped = _newton_step(m, d, ctx)
        return jax.tree.map(lambda new, old: jnp.where(going, new, old), stepped, ctx)

    ctx = mjx_solver.Context.create(m, d)
    if m.opt.iterations == 1:  # as mjx.solve: one step, untested
        ctx = _newton_step(m, d, ctx)
    else:
        ctx = jax.lax.fori_loop(0, m.opt.iterations, iteration, ctx)
    niter = jnp.broadcast_to(ctx.solver_niter, d._impl.solver_niter.shape)
    return d.tree_replace({"qfrc_constraint": ctx.qfrc_constraint, "qacc": ctx.qacc,
                           "_impl.efc_force": ctx.efc_force,
                           "_impl.solver_niter": niter.astype(d._impl.solver_niter.dtype)})


__all__ = ["solve"]
