"""The arm's emulated position motor against PyBullet itself, the original's physics engine.

Drives PyBullet's `franka_panda/panda.urdf` (from `pybullet_data`) with the original's joint
control (reference B2: target `q + 0.05 a` re-anchored every step, POSITION_CONTROL with the
forces 87, 87, 87, 87, 12, 120, 120 and the fingers at 0 with 170, 20 substeps of 1/500 s) and
our MJX physics with the same action sequences from the neutral pose, then reports

- per joint, the least-squares tracking gain and lag (dq_t on 0.05 a_t and 0.05 a_{t-1}) of both
  engines on the same actions, and the open-loop joint difference after 1 ... T steps;
- both engines' gains and lags under other sampling protocols (episodes x steps): the reference's
  lag figures (0.21 and 0.12 on joints 1 and 2) depend on where the random walk takes the arm;
- saturated actions that drive the joints into their limits: how far the engines then part;
- the end-effector IDs' kinematics: the grasp target's position and `calculateInverseKinematics`
  (the original's joint targets) against ours on random joint configurations;
- mode 1's link-to-sphere distances (`getClosestPoints`, the original's labels and features)
  against ours from the env's poses and hulls;
- constant actions that press the arm into the table: how far the engines part in contact;
- random-action episodes with the table whose fingers reach it (nearly all do within 100 steps
  from the neutral pose): the grasp target's drift from PyBullet's, before and after the first
  finger contact.

PyBullet is an optional extra (`pip install -e ".[pybullet]"`; wheels for CPython up to 3.11).
`--write-reference` stores PyBullet's rollouts in `tests/envs/data/` for the CPU test
`tests/envs/test_arm_physics.py::test_motor_matches_pybullet_on_the_same_actions`, which then
needs no PyBullet. The random and saturated rollouts run without the table and floor in both
engines; the pressing and table episodes with them. `--parts table` runs only the table episodes
(and with `--write-reference` replaces only their arrays in the stored file).

    python benchmarks/lab/arm_vs_pybullet.py --write-reference \
        --out benchmarks/results/arm_vs_pybullet.json
    python benchmarks/lab/arm_vs_pybullet.py --parts table --write-reference \
        --out benchmarks/results/arm_vs_pybullet_table.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax.envs.arm import model as arm_model
from specrl_jax.envs.arm import sensors
from specrl_jax.envs.arm.ik import EndEffectorIK
from specrl_jax.envs.arm.physics import SUBSTEPS, Physics

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "tests" / "envs" / "data" / "arm_pybullet_rollouts.npz"
ARM_JOINTS, FINGER_JOINTS, GRASP_TARGET = list(range(7)), [9, 10], 11
MODE1_LINKS = [0, 1, 2, 3, 4, 5, 6, 8, 9, 10]
FORCES = list(arm_model.FORCE_LIMITS) + [170.0, 170.0]


def pybullet_arm():
    """(pybullet module, robot id) of a DIRECT client with the original's timestep and gravity."""
    import pybullet
    import pybullet_data

    pybullet.connect(pybullet.DIRECT)
    pybullet.setAdditionalSearchPath(pybullet_data.getDataPath())
    pybullet.setTimeStep(1 / 500)
    pybullet.setGravity(0, 0, -9.81)
    robot = pybullet.loadURDF("franka_panda/panda.urdf", basePosition=[-0.6, 0, 0],
                              useFixedBase=True)
    return pybullet, robot


def add_table(pybullet) -> int:
    """Adds the original's table and floor (reference B3; Bullet's default friction); returns the
    table's body id."""
    bodies = []
    for half, centre in (([0.55, 0.35, 0.2], [-0.3, 0, -0.2]), ([3, 3, 0.01], [0, 0, -0.41])):
        box = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half)
        bodies.append(pybullet.createMultiBody(0, box, basePosition=centre))
    return bodies[0]


def pybullet_rollouts(actions: np.ndarray, table: bool = False) -> np.ndarray:
    """float64[E, T+1, 7] joint angles (rad) of PyBullet's arm under `actions` float[E, T, 7],
    each episode from the neutral pose at rest; with `table`, the original's table and floor."""
    pybullet, robot = pybullet_arm()
    if table:
        add_table(pybullet)
    angles = lambda: [pybullet.getJointState(robot, j)[0] for j in ARM_JOINTS]
    qpos = np.zeros((actions.shape[0], actions.shape[1] + 1, 7))
    for e, episode in enumerate(actions):
        for j, q in zip(ARM_JOINTS + FINGER_JOINTS, list(arm_model.NEUTRAL_QPOS) + [0.0, 0.0]):
            pybullet.resetJointState(robot, j, q, 0.0)
        qpos[e, 0] = angles()
        for t, action in enumerate(episode):
            target = list(qpos[e, t] + 0.05 * np.clip(action, -1, 1)) + [0.0, 0.0]
            pybullet.setJointMotorControlArray(robot, ARM_JOINTS + FINGER_JOINTS,
                                               pybullet.POSITION_CONTROL,
                                               targetPositions=target, forces=FORCES)
            for _ in range(SUBSTEPS):
                pybullet.stepSimulation()
            qpos[e, t + 1] = angles()
    pybullet.disconnect()
    return qpos


def arm_state(pybullet, robot) -> tuple[np.ndarray, np.ndarray]:
    """PyBullet's joint angles float64[7] (rad) and grasp target float64[3] (m, FK of them)."""
    qpos = np.asarray([pybullet.getJointState(robot, j)[0] for j in ARM_JOINTS])
    point = pybullet.getLinkState(robot, GRASP_TARGET, computeForwardKinematics=True)[4]
    return qpos, np.asarray(point)


def pybullet_table_episodes(count: int, steps: int, seed: int, max_draws: int = 4096) -> dict:
    """PyBullet's episodes with the table and floor, under uniform random joint actions from the
    neutral pose, whose fingers touch the table: the first `count` of those drawn from `seed`.

    Returns a dict of `actions` float32[count, steps, 7], `qpos` float64[count, steps+1, 7]
    (rad), `grasp_target` float64[count, steps+1, 3] (m, FK of `qpos`), `first_contact`
    int32[count] (the env step during which a finger first touches the table) and `drawn`
    (episodes drawn to find them)."""
    pybullet, robot = pybullet_arm()
    table = add_table(pybullet)
    rng = np.random.default_rng(seed)
    kept, drawn = [], 0
    while len(kept) < count and drawn < max_draws:
        drawn += 1
        actions = rng.uniform(-1, 1, (steps, 7)).astype(np.float32)
        for j, q in zip(ARM_JOINTS + FINGER_JOINTS, list(arm_model.NEUTRAL_QPOS) + [0.0, 0.0]):
            pybullet.resetJointState(robot, j, q, 0.0)
        states, first = [arm_state(pybullet, robot)], -1
        for t, action in enumerate(actions):
            target = list(states[-1][0] + 0.05 * action) + [0.0, 0.0]
            pybullet.setJointMotorControlArray(robot, ARM_JOINTS + FINGER_JOINTS,
                                               pybullet.POSITION_CONTROL,
                                               targetPositions=target, forces=FORCES)
            for _ in range(SUBSTEPS):
                pybullet.stepSimulation()
                if first < 0 and any(c[3] in FINGER_JOINTS
                                     for c in pybullet.getContactPoints(robot, table)):
                    first = t
            states.append(arm_state(pybullet, robot))
        if first >= 0:
            qpos, points = (np.stack(x) for x in zip(*states))
            kept.append((actions, qpos, points, first))
    pybullet.disconnect()
    actions, qpos, points, first = (np.stack(x) for x in zip(*kept))
    return {"actions": actions, "qpos": qpos, "grasp_target": points,
            "first_contact": first.astype(np.int32), "drawn": drawn}


def table_drift(theirs: dict, ours_qpos: np.ndarray) -> dict:
    """The grasp target's distance (m) from PyBullet's in the table episodes `theirs`
    (`pybullet_table_episodes`), ours from our joint angles `ours_qpos` float[E, T+1, 7]:
    median and max over episodes after 10, 20, 50 and 100 steps, and the largest before each
    episode's first finger contact."""
    points = our_grasp_target(ours_qpos.reshape(-1, 7)).reshape(*ours_qpos.shape[:2], 3)
    gap = np.linalg.norm(points - theirs["grasp_target"], axis=-1)
    before = max(gap[e, :f + 1].max() for e, f in enumerate(theirs["first_contact"]))
    return {"steps": {str(t): {"median": float(np.median(gap[:, t])), "max": float(gap[:, t].max())}
                      for t in (10, 20, 50, 100) if t < gap.shape[1]},
            "before_first_contact_max": float(before)}


def pybullet_grasp_target(qpos: np.ndarray) -> np.ndarray:
    """float64[K, 3]: PyBullet's grasp-target position (FK) at joint angles `qpos` float[K, 7]."""
    pybullet, robot = pybullet_arm()
    points = []
    for q in qpos:
        for j, angle in zip(ARM_JOINTS, q):
            pybullet.resetJointState(robot, j, angle, 0.0)
        points.append(pybullet.getLinkState(robot, GRASP_TARGET, computeForwardKinematics=True)[4])
    pybullet.disconnect()
    return np.asarray(points)


def pybullet_ik(qpos: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """float64[K, 7]: PyBullet's `calculateInverseKinematics` joint angles from `qpos`
    float[K, 7] toward `targets` float[K, 3] with the gripper down (the original's end-effector
    control, no optional arguments)."""
    pybullet, robot = pybullet_arm()
    solved = []
    for q, target in zip(qpos, targets):
        for j, angle in zip(ARM_JOINTS, q):
            pybullet.resetJointState(robot, j, angle, 0.0)
        solved.append(pybullet.calculateInverseKinematics(robot, GRASP_TARGET, list(target),
                                                          [1.0, 0.0, 0.0, 0.0])[:7])
    pybullet.disconnect()
    return np.asarray(solved)


def our_grasp_target(qpos: np.ndarray) -> np.ndarray:
    """float64[K, 3]: our grasp-target position (m) at joint angles `qpos` float[K, 7]."""
    ik = EndEffectorIK(arm_model.load_model(table_contacts=False))
    points = jax.jit(jax.vmap(lambda x: ik.pose(x)[0]))(jnp.asarray(qpos, jnp.float32))
    return np.asarray(points, np.float64)


def our_ik(qpos: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grasp target float64[K, 3] at `qpos` and the IK's joint angles float64[K, 7] toward
    `targets`, from our kinematics and IK (float32, jitted)."""
    ik = EndEffectorIK(arm_model.load_model(table_contacts=False))
    q, t = jnp.asarray(qpos, jnp.float32), jnp.asarray(targets, jnp.float32)
    points = jax.jit(jax.vmap(lambda x: ik.pose(x)[0]))(q)
    return np.asarray(points, np.float64), np.asarray(jax.jit(jax.vmap(ik.solve))(q, t), np.float64)


def pybullet_link_distances(qpos: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """float64[K, 10, Z]: PyBullet's signed distances (m) from the mode-1 links (the original's
    `[0, ..., 6, 8, 9, 10]`) to spheres of `radius` at `centres` float[K, Z, 3], the arm at
    `qpos` float[K, 7] (`getClosestPoints`, as the original's labels and features)."""
    pybullet, robot = pybullet_arm()
    shape = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=radius)
    spheres = [pybullet.createMultiBody(0, shape, basePosition=[0, 0, 5 + i])
               for i in range(centres.shape[1])]
    out = np.zeros((len(qpos), len(MODE1_LINKS), centres.shape[1]))
    for k, (q, where) in enumerate(zip(qpos, centres)):
        for j, angle in zip(ARM_JOINTS, q):
            pybullet.resetJointState(robot, j, angle, 0.0)
        for sphere, centre in zip(spheres, where):
            pybullet.resetBasePositionAndOrientation(sphere, list(centre), [0, 0, 0, 1])
        for li, link in enumerate(MODE1_LINKS):
            for z, sphere in enumerate(spheres):
                points = pybullet.getClosestPoints(robot, sphere, 10.0, linkIndexA=link)
                out[k, li, z] = min(point[8] for point in points)
    pybullet.disconnect()
    return out


def our_link_distances(qpos: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """`pybullet_link_distances`' figures from `PandaLTLReach1Joints-v0`'s own poses and hulls."""
    env, params = specrl_jax.make("PandaLTLReach1Joints-v0")
    hulls = arm_model.link_hulls()

    def distances(q, where):
        _, state = env.reset_to(jax.random.key(0), {"region_pos": where, "joint_qpos": q}, params)
        pose = env.poses(state)
        return sensors.link_sphere_distances(pose["link_pos"], pose["link_mat"], hulls,
                                             state.region_pos, jnp.asarray(env.region_radius))[0]

    out = jax.jit(jax.vmap(distances))(jnp.asarray(qpos, jnp.float32),
                                       jnp.asarray(centres, jnp.float32))
    return np.asarray(out, np.float64)


def our_rollouts(actions: np.ndarray, table: bool = False) -> np.ndarray:
    """float64[E, T+1, 7] joint angles of our MJX arm under `actions` (table and floor contacts
    with `table`)."""
    physics = Physics(arm_model.load_model(table_contacts=table), arm_model.FORCE_LIMITS)
    step = jax.jit(jax.vmap(lambda s, a: physics.step(s, s.qpos + 0.05 * a)))
    neutral = jnp.asarray(arm_model.NEUTRAL_QPOS, jnp.float32)
    state = jax.vmap(lambda _: physics.init(neutral))(jnp.arange(actions.shape[0]))
    qpos = [np.asarray(state.qpos)]
    for t in range(actions.shape[1]):
        state = step(state, jnp.asarray(actions[:, t], jnp.float32))
        qpos.append(np.asarray(state.qpos))
    return np.stack(qpos, 1).astype(np.float64)


def gains_and_lags(actions: np.ndarray, qpos: np.ndarray) -> np.ndarray:
    """float[7, 2]: per joint, the least-squares (gain, lag) of dq_t on 0.05 a_t and
    0.05 a_{t-1} (the reference's measurement, B2)."""
    commanded, moved = 0.05 * np.clip(actions, -1, 1), np.diff(qpos, axis=1)
    fits = []
    for j in range(7):
        x = np.stack([commanded[:, 1:, j].ravel(), commanded[:, :-1, j].ravel()], 1)
        fits.append(np.linalg.lstsq(x, moved[:, 1:, j].ravel(), rcond=None)[0])
    return np.asarray(fits)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write-reference", action="store_true",
                        help=f"store PyBullet's rollouts in {REFERENCE.relative_to(ROOT)}")
    parser.add_argument("--out", default=None, help="a JSON file of the figures")
    parser.add_argument("--parts", choices=("all", "table"), default="all",
                        help="table: only the random-action episodes that touch the table")
    parser.add_argument("--table-episodes", type=int, default=32,
                        help="table episodes to record (the fingers reach the table)")
    args = parser.parse_args()
    import pybullet  # noqa: F401  (fail before any work when it is missing)

    if args.parts == "table":
        table_main(args)
        return

    actions = np.random.default_rng(args.seed).uniform(
        -1, 1, (args.episodes, args.steps, 7)).astype(np.float32)
    theirs = pybullet_rollouts(actions)
    start = time.perf_counter()
    ours = our_rollouts(actions)
    ours_s = time.perf_counter() - start
    fit_theirs, fit_ours = gains_and_lags(actions, theirs), gains_and_lags(actions, ours)
    print(f"{args.episodes} episodes x {args.steps} steps from the neutral pose, the same actions "
          f"(ours {ours_s:.1f} s on {jax.devices()[0].platform})")
    print("joint  PyBullet gain / lag    ours gain / lag")
    for j in range(7):
        print(f"j{j + 1}     {fit_theirs[j, 0]:.3f} / {fit_theirs[j, 1]:+.3f}        "
              f"{fit_ours[j, 0]:.3f} / {fit_ours[j, 1]:+.3f}")
    gap = np.abs(theirs - ours)
    horizons = [t for t in (1, 2, 5, 10, 25, 50, 100, 200) if t <= args.steps]
    for t in horizons:
        print(f"after {t:3d} steps: joint difference max {gap[:, t].max():.2e} rad, "
              f"mean {gap[:, t].mean():.2e}")

    protocols = {}
    for episodes, steps in ((1, 1000), (5, 200), (20, 200)):
        sample = np.random.default_rng(args.seed).uniform(
            -1, 1, (episodes, steps, 7)).astype(np.float32)
        protocols[f"{episodes}x{steps}"] = {
            "pybullet": gains_and_lags(sample, pybullet_rollouts(sample)),
            "ours": gains_and_lags(sample, our_rollouts(sample))}
    print("other protocols, gain / lag of joints 1 and 2 "
          "(the reference's 0.61 / 0.21, 0.50 / 0.12):")
    for name, fits in protocols.items():
        for engine, fit in fits.items():
            print(f"  {name:>8} {engine:>8}: j1 {fit[0, 0]:.3f} / {fit[0, 1]:+.3f}   "
                  f"j2 {fit[1, 0]:.3f} / {fit[1, 1]:+.3f}")

    # saturated actions drive joints into their limits, which Bullet solves with the motor
    saturated = np.stack([np.ones((60, 7)), -np.ones((60, 7)),
                          np.tile([1, -1, 1, -1, 1, -1, 1], (60, 1))]).astype(np.float32)
    sat_theirs, sat_ours = pybullet_rollouts(saturated), our_rollouts(saturated)
    ranges = arm_model.load_model(table_contacts=False).jnt_range[:7]
    beyond = np.maximum(sat_ours - ranges[:, 1], ranges[:, 0] - sat_ours).max(axis=(0, 1))
    sat_gap = np.abs(sat_theirs - sat_ours).max(axis=(0, 1))
    their_beyond = np.maximum(sat_theirs - ranges[:, 1], ranges[:, 0] - sat_theirs).max()
    print("saturated actions (all +1, all -1, alternating; 60 steps): largest joint difference "
          + " ".join(f"{g:.3f}" for g in sat_gap) + " rad; ours beyond a limit by at most "
          f"{max(beyond.max(), 0.0):.4f} rad (PyBullet "
          f"{max(their_beyond, 0.0):.4f})")

    # constant actions that press the arm into the table (joint 2 forward, with 4 or 6) or not
    pressing = {"2+": [0, 1, 0, 0, 0, 0, 0], "2+ 4+": [0, 1, 0, 1, 0, 0, 0],
                "2+ 4-": [0, 1, 0, -1, 0, 0, 0], "2+ 6-": [0, 1, 0, 0, 0, -1, 0],
                "4+ (no contact)": [0, 0, 0, 1, 0, 0, 0]}
    press = np.stack([np.tile(v, (60, 1)) for v in pressing.values()]).astype(np.float32)
    press_theirs = pybullet_rollouts(press, table=True)
    press_gap = np.abs(press_theirs - our_rollouts(press, table=True)).max(axis=(1, 2))
    print("the table: constant actions for 60 steps, largest joint difference: "
          + ", ".join(f"joints {k} {g:.3f}" for k, g in zip(pressing, press_gap)) + " rad")

    rng = np.random.default_rng(args.seed)
    ik_qpos = np.asarray(arm_model.NEUTRAL_QPOS) + rng.uniform(-0.3, 0.3, (32, 7))
    ik_qpos[0] = arm_model.NEUTRAL_QPOS
    their_points = pybullet_grasp_target(ik_qpos)
    ik_targets = their_points + 0.05 * rng.uniform(-1, 1, (32, 3))
    their_ik = pybullet_ik(ik_qpos, ik_targets)
    our_points, our_solved = our_ik(ik_qpos, ik_targets)
    fk_gap, ik_gap = np.abs(their_points - our_points).max(), np.abs(their_ik - our_solved).max()
    print(f"32 joint configurations (neutral +- 0.3 rad), targets 5 cm away: grasp-target FK "
          f"apart by {fk_gap:.1e} m, calculateInverseKinematics vs ours {ik_gap:.1e} rad")

    # mode-1 distances: 8 spheres (the benchmark's radius) placed near random link points
    dist_qpos = np.asarray(arm_model.NEUTRAL_QPOS) + rng.uniform(-0.4, 0.4, (24, 7))
    dist_centres = pybullet_grasp_target(dist_qpos)[:, None] + rng.normal(0, 0.12, (24, 8, 3))
    their_dist = pybullet_link_distances(dist_qpos, dist_centres, 0.06)
    our_dist = our_link_distances(dist_qpos, dist_centres)
    near = np.abs(their_dist) < 0.1
    offset = (their_dist - our_dist)[near]
    touch_agree = ((their_dist <= 0) == (our_dist <= 0))[np.abs(their_dist) < 0.02].mean()
    print(f"mode-1 link-sphere distances, {near.sum()} pairs within 10 cm: PyBullet - ours median "
          f"{np.median(offset) * 1e3:.3f} mm (range {offset.min() * 1e3:.3f} .. "
          f"{offset.max() * 1e3:.3f}; PyBullet's collision margin); touch labels agree on "
          f"{touch_agree:.3f} of the pairs within 2 cm")

    if args.write_reference:
        import pybullet as pb_module

        REFERENCE.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(REFERENCE, actions=actions, qpos=theirs, ik_qpos=ik_qpos,
                            ik_targets=ik_targets, ik_grasp_target=their_points, ik_joints=their_ik,
                            saturated_actions=saturated, saturated_qpos=sat_theirs,
                            press_actions=press, press_qpos=press_theirs,
                            dist_qpos=dist_qpos, dist_centres=dist_centres,
                            dist_pybullet=their_dist,
                            pybullet_version=str(pb_module.getAPIVersion()))
        print(f"wrote {REFERENCE}")
    if args.out:
        import pybullet as pb_module

        record = {
            "episodes": args.episodes, "steps": args.steps, "seed": args.seed,
            "pybullet_api_version": pb_module.getAPIVersion(),
            "gain_lag": {"pybullet": fit_theirs.round(4).tolist(),
                         "ours": fit_ours.round(4).tolist()},
            "joint_difference_rad": {str(t): {"max": float(gap[:, t].max()),
                                              "mean": float(gap[:, t].mean())} for t in horizons},
            "protocols": {k: {e: f.round(4).tolist() for e, f in v.items()}
                          for k, v in protocols.items()},
            "ik_32_configurations": {"grasp_target_fk_max_m": float(fk_gap),
                                     "ik_joint_max_rad": float(ik_gap)},
            "mode1_distances": {"pairs_within_10cm": int(near.sum()),
                                "pybullet_minus_ours_median_m": float(np.median(offset)),
                                "pybullet_minus_ours_min_m": float(offset.min()),
                                "pybullet_minus_ours_max_m": float(offset.max()),
                                "touch_agreement_within_2cm": float(touch_agree)},
            "table_60_steps_joint_difference_max_rad": dict(zip(pressing,
                                                                press_gap.round(4).tolist())),
            "saturated_60_steps": {"joint_difference_max_rad": sat_gap.round(4).tolist(),
                                   "ours_beyond_limit_max_rad": float(max(beyond.max(), 0.0))},
            "versions": {"jax": jax.__version__, "device": str(jax.devices()[0])},
            "date": time.strftime("%Y-%m-%d"),
        }
        Path(args.out).write_text(json.dumps(record, indent=1))
        print(f"wrote {args.out}")


def table_main(args: argparse.Namespace) -> None:
    """The random-action episodes that touch the table: PyBullet's against ours."""
    theirs = pybullet_table_episodes(args.table_episodes, args.steps, args.seed)
    ours = our_rollouts(theirs["actions"], table=True)
    drift = table_drift(theirs, ours)
    print(f"{len(theirs['actions'])} of {theirs['drawn']} random-action episodes touch the table "
          f"with the fingers (first contact at steps {theirs['first_contact'].min()}-"
          f"{theirs['first_contact'].max()}); grasp target from PyBullet's, before the first "
          f"contact at most {drift['before_first_contact_max'] * 1e3:.2f} mm")
    for t, fig in drift["steps"].items():
        print(f"  after {t:>3} steps: median {fig['median'] * 100:.2f} cm, max "
              f"{fig['max'] * 100:.2f} cm")
    if args.write_reference:
        stored = dict(np.load(REFERENCE)) if REFERENCE.exists() else {}
        stored.update(table_actions=theirs["actions"],
                      table_qpos=theirs["qpos"].astype(np.float32),
                      table_grasp_target=theirs["grasp_target"].astype(np.float32),
                      table_first_contact=theirs["first_contact"])
        np.savez_compressed(REFERENCE, **stored)
        print(f"wrote the table episodes to {REFERENCE}")
    if args.out:
        record = {"episodes": len(theirs["actions"]), "drawn": theirs["drawn"],
                  "steps": args.steps, "seed": args.seed,
                  "first_contact_steps": theirs["first_contact"].tolist(),
                  "grasp_target_drift_m": drift,
                  "pybullet_api_version": pybullet_api_version(),
                  "versions": {"jax": jax.__version__, "device": str(jax.devices()[0])},
                  "date": time.strftime("%Y-%m-%d")}
        Path(args.out).write_text(json.dumps(record, indent=1))
        print(f"wrote {args.out}")


def pybullet_api_version() -> int:
    import pybullet

    return pybullet.getAPIVersion()


if __name__ == "__main__":
    main()
