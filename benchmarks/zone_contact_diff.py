"""The Ant's contact problem, MJX-JAX against MuJoCo C, stage by stage (CPU, float64).

MuJoCo C settles the Ant from its spawn pose at zero control for `--settle` substeps; then, for
each of `--states` random controls, `mujoco.mj_forward` and `mjx.forward` run on the same
qpos/qvel/ctrl and the constraint pipeline is compared in order: detected contacts (geoms,
distance, position), contact frame, friction / solref / solimp, the constraint rows (`efc_J`,
`efc_pos`, `efc_margin`, `efc_frictionloss`, `efc_D`, `efc_aref`; MJX pads rows for contacts that
are not active, so its active rows are matched to C's: limit rows by their Jacobian, contact
rows by contact geom pair and position in the contact), `efc_force`, `qfrc_constraint`, `qacc`.
Prints a table per state and names the first stage that differs.

With `--c-frame`, MJX gets MuJoCo C's plane-capsule contact frame (specrl_jax's
`contact_frame.c_contact_frame()`, what `Physics` uses) and the pipelines agree to rounding;
without it MJX 3.17's own collider runs. `--one-step STEPS` instead measures the per-env-step
error of MJX (MJX's frame, C's frame, elliptic cone) and of the elliptic cone in C, from C states.
`--integrator STEPS` compares one physics substep from C states: MJX (C's frame) against MuJoCo
C's `mj_step` and against the classic RK4 (`classic_rk4_step`) evaluated with C's `mj_forward`, for
the Ant's RK4 and, as a control, Euler.

Usage: python benchmarks/zone_contact_diff.py [--cone pyramidal|elliptic] [--states 3]
       [--settle 300] [--iterations 100] [--c-frame]
       python benchmarks/zone_contact_diff.py --one-step 20 --seeds 2 --settle 100 --iterations 8
       python benchmarks/zone_contact_diff.py --integrator 10 --seeds 2 --settle 100
"""

from __future__ import annotations

import argparse
import contextlib

import jax

jax.config.update("jax_enable_x64", True)

import mujoco
import numpy as np
from mujoco import mjx

from specrl_jax.envs.zone.c_reference import classic_rk4_step
from specrl_jax.envs.zone.contact_frame import c_contact_frame
from specrl_jax.envs.zone.models import Solver, load_model

#: Relative tolerance of "equal" (float64 pipelines; the solvers stop at tolerance 1e-8).
RTOL = 1e-6
CONTACT_ROWS = (
    int(mujoco.mjtConstraint.mjCNSTR_CONTACT_PYRAMIDAL),
    int(mujoco.mjtConstraint.mjCNSTR_CONTACT_ELLIPTIC),
)


def rows_per_contact(model: mujoco.MjModel, condim: int) -> int:
    elliptic = model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    return condim if elliptic or condim == 1 else 2 * (condim - 1)


def match(model: mujoco.MjModel, c: mujoco.MjData, x: mjx.Data) -> tuple[np.ndarray, np.ndarray]:
    """(MJX contact index per C contact, MJX efc row per C efc row): int arrays."""
    xc = x._impl.contact
    geoms, dist = np.asarray(xc.geom), np.asarray(xc.dist)
    active = dist < np.asarray(xc.includemargin)
    contact = np.array([
        np.nonzero(active & (geoms == c.contact.geom[i]).all(1))[0][0] for i in range(c.ncon)
    ], dtype=int)
    jac = np.asarray(x._impl.efc_J)
    address = np.asarray(xc.efc_address)
    contact_rows = np.zeros(len(jac), bool)
    for a, k in zip(address, np.asarray(xc.dim)):
        contact_rows[a:a + rows_per_contact(model, int(k))] = True
    others = np.nonzero((np.abs(jac).sum(1) > 0) & ~contact_rows)[0]
    jc = c.efc_J.reshape(c.nefc, model.nv)
    rows = np.empty(c.nefc, dtype=int)
    for r in range(c.nefc):
        if c.efc_type[r] in CONTACT_ROWS:
            i = c.efc_id[r]
            rows[r] = address[contact[i]] + r - c.contact.efc_address[i]
        else:
            rows[r] = others[np.abs(jac[others] - jc[r]).max(1).argmin()]
    return contact, rows


def stages(model: mujoco.MjModel, c: mujoco.MjData, x: mjx.Data) -> list[tuple[str, float, float]]:
    """(stage, max |MJX - C|, max |C|) in pipeline order."""
    contact, rows = match(model, c, x)
    xc, xi = x._impl.contact, x._impl
    pick = lambda a: np.asarray(a)[contact]
    out = [
        ("contact.dist", pick(xc.dist), c.contact.dist),
        ("contact.pos", pick(xc.pos), c.contact.pos),
        ("contact.frame", pick(xc.frame).reshape(-1, 9), c.contact.frame),
        ("contact.friction", pick(xc.friction), c.contact.friction),
        ("contact.solref", pick(xc.solref), c.contact.solref),
        ("contact.solimp", pick(xc.solimp), c.contact.solimp),
        ("efc_J", np.asarray(xi.efc_J)[rows], c.efc_J.reshape(c.nefc, model.nv)),
        ("efc_pos", np.asarray(xi.efc_pos)[rows], c.efc_pos),
        ("efc_margin", np.asarray(xi.efc_margin)[rows], c.efc_margin),
        ("efc_frictionloss", np.asarray(xi.efc_frictionloss)[rows], c.efc_frictionloss),
        ("efc_D", np.asarray(xi.efc_D)[rows], c.efc_D),
        ("efc_aref", np.asarray(xi.efc_aref)[rows], c.efc_aref),
        ("efc_force", np.asarray(xi.efc_force)[rows], c.efc_force),
        ("qfrc_constraint", np.asarray(x.qfrc_constraint), c.qfrc_constraint),
        ("qacc", np.asarray(x.qacc), c.qacc),
    ]
    return [(name, float(np.abs(a - b).max()), float(np.abs(b).max())) for name, a, b in out]


def one_step(settle: int, steps: int, seeds: int, iterations: int) -> None:
    """Per-env-step model error: along MuJoCo C trajectories of the original's model (pyramidal
    cone) under random actions, each variant runs one env step (10 RK4 substeps) from C's state;
    prints the max and median |variant - reference| of qpos and of the body position."""
    models = {
        cone: load_model("Ant", Solver(iterations=iterations, ls_iterations=4, condim=6, cone=cone))
        for cone in ("pyramidal", "elliptic")
    }
    states = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        data = mujoco.MjData(models["pyramidal"])
        data.qpos[:] = models["pyramidal"].qpos0
        for _ in range(settle):
            mujoco.mj_step(models["pyramidal"], data)
        for _ in range(steps):
            data.ctrl[:] = rng.uniform(-1, 1, data.ctrl.size)
            states.append((data.qpos.copy(), data.qvel.copy(), data.ctrl.copy()))
            for _ in range(10):
                mujoco.mj_step(models["pyramidal"], data)

    def c_step(cone: str) -> np.ndarray:
        out = []
        for qpos, qvel, ctrl in states:
            data = mujoco.MjData(models[cone])
            data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
            for _ in range(10):
                mujoco.mj_step(models[cone], data)
            out.append(data.qpos.copy())
        return np.array(out)

    def mjx_step(cone: str, c_frame: bool) -> np.ndarray:
        with c_contact_frame() if c_frame else contextlib.nullcontext():
            model, mx = models[cone], mjx.put_model(models[cone])
            step = jax.jit(lambda x: jax.lax.fori_loop(
                0, 9, lambda _, y: mjx.step(mx, y), mjx.step(mx, x)))
            out = []
            for qpos, qvel, ctrl in states:
                data = mujoco.MjData(model)
                data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
                out.append(np.asarray(step(mjx.put_data(model, data)).qpos))
            return np.array(out)

    c_pyr, c_ell = c_step("pyramidal"), c_step("elliptic")
    rows = (
        ("C elliptic vs C pyramidal (the original)", c_ell, c_pyr),
        ("MJX pyramidal vs C pyramidal", mjx_step("pyramidal", False), c_pyr),
        ("MJX pyramidal, C's frame vs C pyramidal", mjx_step("pyramidal", True), c_pyr),
        ("MJX elliptic vs C elliptic", mjx_step("elliptic", False), c_ell),
    )
    print(f"\none env step from {len(states)} C states ({seeds} seeds x {steps} steps after "
          f"{settle} settling substeps), Newton {iterations}/4, float64")
    print(f"{'comparison':42s} {'qpos max':>9s} {'median':>9s} {'body max':>9s} {'median':>9s}")
    for name, a, b in rows:
        q, body = np.abs(a - b).max(1), np.abs(a[:, :3] - b[:, :3]).max(1)
        print(f"{name:42s} {q.max():9.2e} {np.median(q):9.2e} {body.max():9.2e} "
              f"{np.median(body):9.2e}")


def integrator(settle: int, steps: int, seeds: int) -> None:
    """One substep from C states (the original's model, `steps` random controls per seed after
    `settle` substeps): max and median |qpos difference| of MJX (C's frame) against C's
    `mj_step` and against `classic_rk4_step`, with RK4 and with Euler."""
    print(f"\none substep from {seeds * steps} C states, Newton 100/50, float64: max / median "
          "|qpos difference|")
    for name in ("RK4", "EULER"):
        model = load_model("Ant", Solver(iterations=100, ls_iterations=50, condim=6))
        model.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{name}")
        mx = mjx.put_model(model)
        with c_contact_frame():
            step = jax.jit(lambda x, mx=mx: mjx.step(mx, x))
            diffs = []
            for seed in range(seeds):
                rng = np.random.default_rng(seed)
                data = mujoco.MjData(model)
                data.qpos[:] = model.qpos0
                for _ in range(settle):
                    mujoco.mj_step(model, data)
                for _ in range(steps):
                    data.ctrl[:] = rng.uniform(-1, 1, model.nu)
                    for _ in range(10):
                        mujoco.mj_step(model, data)
                    own, classic = mujoco.MjData(model), mujoco.MjData(model)
                    for d in (own, classic):
                        d.qpos[:], d.qvel[:], d.ctrl[:] = data.qpos, data.qvel, data.ctrl
                    x = np.asarray(step(mjx.put_data(model, own)).qpos)
                    mujoco.mj_step(model, own)
                    classic_rk4_step(model, classic)
                    diffs.append([np.abs(x - own.qpos).max(), np.abs(x - classic.qpos).max(),
                                  np.abs(classic.qpos - own.qpos).max()])
        diffs = np.array(diffs)
        for i, label in enumerate(("MJX vs C mj_step", "MJX vs classic RK4 on C",
                                   "classic RK4 on C vs C mj_step")):
            if name == "EULER" and i:
                continue
            print(f"{name:6s} {label:32s} {diffs[:, i].max():9.2e} {np.median(diffs[:, i]):9.2e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cone", default="pyramidal", choices=("pyramidal", "elliptic"))
    parser.add_argument("--states", type=int, default=3)
    parser.add_argument("--settle", type=int, default=300)
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--c-frame", action="store_true",
                        help="give MJX MuJoCo C's plane-capsule contact frame (specrl_jax's "
                             "contact_frame.c_contact_frame, as the env's physics does)")
    parser.add_argument("--one-step", type=int, default=0, metavar="STEPS",
                        help="instead: per-env-step errors over STEPS steps of --seeds seeds")
    parser.add_argument("--integrator", type=int, default=0, metavar="STEPS",
                        help="instead: one substep of MJX, C and the classic RK4 from C states")
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    if args.integrator:
        integrator(args.settle, args.integrator, args.seeds)
        return
    if args.one_step:
        one_step(args.settle, args.one_step, args.seeds, args.iterations)
        return
    solver = Solver(iterations=args.iterations, ls_iterations=50, condim=6, cone=args.cone)
    model = load_model("Ant", solver)
    print(f"mujoco {mujoco.__version__}, jax {jax.__version__}, float64; cone {args.cone}, "
          f"impratio {model.opt.impratio}, noslip {model.opt.noslip_iterations}, "
          f"jacobian {mujoco.mjtJacobian(model.opt.jacobian).name}, "
          f"disableflags {model.opt.disableflags}, Newton {args.iterations}/50, "
          f"MJX plane-capsule frame: {'C rule' if args.c_frame else 'MJX 3.17'}")
    data = mujoco.MjData(model)
    data.qpos[:] = model.qpos0
    for _ in range(args.settle):
        mujoco.mj_step(model, data)
    with c_contact_frame() if args.c_frame else contextlib.nullcontext():
        forward = jax.jit(lambda m, d: mjx.forward(m, d)).lower(
            mjx.put_model(model), mjx.put_data(model, data)).compile()
    mx = mjx.put_model(model)
    rng = np.random.default_rng(0)
    for state in range(args.states):
        data.ctrl[:] = rng.uniform(-1, 1, model.nu)
        mujoco.mj_forward(model, data)
        x = forward(mx, mjx.put_data(model, data))
        print(f"\nstate {state}: {data.ncon} contacts, {data.nefc} constraint rows in C")
        print(f"{'stage':18s} {'max|MJX-C|':>12s} {'max|C|':>12s}")
        first = None
        for name, diff, scale in stages(model, data, x):
            bad = diff > RTOL * max(scale, 1.0)
            first = first or (name if bad else None)
            print(f"{name:18s} {diff:12.3e} {scale:12.3e}{'  <- differs' if bad else ''}")
        print(f"first differing stage: {first or 'none'}")


if __name__ == "__main__":
    main()
