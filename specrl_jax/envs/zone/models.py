"""MJCF models of the Zone robots (Point, Car, Ant), written for this project from the facts.

Each robot keeps the original's bodies, joints, geometry, densities, damping, actuator gains,
force ranges, timestep and integrator. Zones and walls are not in the physics model at all: they
never collide in the original, so they are pure JAX state (zone discs) and a threshold (walls).

Collision pruning (see `docs/fidelity.md`): every robot geom that may touch the floor has
`contype=1 conaffinity=0` and the floor `contype=0 conaffinity=1`, so the robot collides with the
floor only; robot-robot self-contacts are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np


@dataclass(frozen=True)
class Solver:
    """Solver settings of the physics model; the default is MuJoCo's (the original's).

    `cone` is the friction cone, "pyramidal" (the original's) or "elliptic". For capsules within
    30 degrees of the floor normal (the Ant's feet) MJX's own collider orients the contact's
    tangents along world y, MuJoCo C along the capsule; a pyramidal cone is not
    rotation-invariant, so the contact problems would differ. Both backends make these contacts
    with C's frame (`contact_frame.py`, `warp_contact_frame.py`). An elliptic
    cone with isotropic friction is the same problem under either frame.

    Speed settings of MJX-JAX (MuJoCo C runs the same model without them):
    `max_contacts` > 0 passes only the K deepest contacts of each step to the solver (MJX's
    `max_contact_points`; 0: every contact slot, each a block of constraint rows whether it
    touches or not); it changes nothing while at most K contacts penetrate. `substep_sensors`
    False skips the sensors in the physics substeps (only the forward pass after the last one
    feeds the observation; sensors never act on the dynamics). `unroll` unrolls the substep loop.
    `small_cholesky` factors the mass matrix and the Newton Hessian with written-out arithmetic
    that XLA fuses instead of library calls (`small_linalg.py`; equal to rounding).
    """

    iterations: int = 100
    ls_iterations: int = 50
    condim: int = 6
    prune_contacts: bool = True
    cone: str = "pyramidal"
    max_contacts: int = 0
    substep_sensors: bool = False
    unroll: int = 1
    small_cholesky: bool = False

    def __post_init__(self) -> None:
        if self.cone not in ("pyramidal", "elliptic"):
            raise ValueError(f"cone must be 'pyramidal' or 'elliptic', got {self.cone!r}")
        for name, low in (("max_contacts", 0), ("unroll", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"{name} must be an int >= {low}, got {value!r}")

    def option(self) -> str:
        return (
            f'iterations="{self.iterations}" ls_iterations="{self.ls_iterations}" '
            f'cone="{self.cone}"'
        )

    def custom(self) -> str:
        """MJX's `max_contact_points` numeric (MuJoCo C ignores it), or nothing."""
        if not self.max_contacts:
            return ""
        numeric = f'<numeric name="max_contact_points" data="{self.max_contacts}"/>'
        return f"<custom>{numeric}</custom>"

    def floor(self) -> str:
        bits = 'contype="0" conaffinity="1"' if self.prune_contacts else ""
        return f'<geom name="floor" type="plane" size="3.5 3.5 0.1" condim="{self.condim}" {bits}/>'

    def contact(self, touches_floor: bool) -> str:
        """Collision attributes of a robot geom: with pruning, only floor-touching geoms
        collide, and only with the floor."""
        if not self.prune_contacts:
            return f'condim="{self.condim}"'
        bits = 'contype="1" conaffinity="0"' if touches_floor else 'contype="0" conaffinity="0"'
        return f'condim="{self.condim}" {bits}'


@dataclass(frozen=True)
class Robot:
    """Static facts of one robot.

    Attributes:
        name: "Point", "Car" or "Ant".
        timestep: physics step, seconds.
        z_height: the original's spawn height of the robot body, metres (our Car starts at
            `start_height` instead).
        keepout: layout keepout of the agent, metres.
        action_dim: number of actuators.
        ego_keys: the original's robot-sensor keys and their sizes, alphabetical (lidar and
            wall sensor excluded).
    """

    name: str
    timestep: float
    z_height: float
    keepout: float
    action_dim: int
    ego_keys: tuple[tuple[str, int], ...]

    @property
    def ego_size(self) -> int:
        return sum(size for _, size in self.ego_keys)


_IMU = (("accelerometer", 3), ("gyro", 3), ("magnetometer", 3), ("velocimeter", 3))
_ANT_JOINTS = tuple(f"{kind}_{leg}" for leg in range(1, 5) for kind in ("hip", "ankle"))

ROBOTS: dict[str, Robot] = {
    "Point": Robot("Point", 0.002, 0.1, 0.4, 2, _IMU),
    "Car": Robot(
        "Car", 0.004, 0.1, 0.4, 2,
        tuple(sorted(_IMU + (("ballangvel_rear", 3), ("ballquat_rear", 9)))),
    ),
    "Ant": Robot(
        "Ant", 0.01, 0.18, 0.4, 8,
        tuple(
            sorted(
                _IMU
                + (("agent_pos", 1), ("agent_qvel", 3))
                + tuple((j, 2) for j in _ANT_JOINTS)
                + tuple((f"{j}_vel", 1) for j in _ANT_JOINTS)
            )
        ),
    ),
}


def _imu_sensors() -> str:
    return "".join(
        f'<{kind} site="agent" name="{kind}"/>'
        for kind in ("accelerometer", "velocimeter", "gyro", "magnetometer")
    )


def point_xml(solver: Solver) -> str:
    """Point: a sphere on two slide joints and a yaw hinge; a site motor along body +x and a
    velocity servo on yaw (both force-limited to 0.05, gear 0.3). Height is not a degree of
    freedom, so the sphere's floor contact exerts no force: with pruning it is removed."""
    limits = 'ctrlrange="-1 1" ctrllimited="true" forcerange="-0.05 0.05" forcelimited="true"'
    return f"""
<mujoco model="zone_point">
  <option timestep="0.002" {solver.option()}/>
  {solver.custom()}
  <worldbody>
    {solver.floor()}
    <body name="agent" pos="0 0 0.1">
      <joint name="x" type="slide" axis="1 0 0" damping="0.01"/>
      <joint name="y" type="slide" axis="0 1 0" damping="0.01"/>
      <joint name="z" type="hinge" axis="0 0 1" damping="0.005"/>
      <geom name="agent" type="sphere" size="0.1" density="1" friction="1 0.01 0.01"
            {solver.contact(False)}/>
      <geom name="pointarrow" type="box" pos="0.1 0 0" size="0.05 0.05 0.05" density="1"
            {solver.contact(False)}/>
      <site name="agent" type="sphere" size="0.032"/>
    </body>
  </worldbody>
  <sensor>{_imu_sensors()}</sensor>
  <actuator>
    <motor name="x" site="agent" gear="0.3 0 0 0 0 0" {limits}/>
    <velocity name="z" joint="z" gear="0.3" kv="1" {limits}/>
  </actuator>
</mujoco>"""


def car_xml(solver: Solver) -> str:
    """Car: a box chassis on a free joint, two driven wheels at +y (torque-limited to 0.02) and
    a ball caster at -y (the front). With pruning only the wheels (cylinders, radius 0.05) and
    the caster touch the floor: the chassis never did in 5,000 random-action steps."""
    box = f'type="box" density="5" {solver.contact(False)}'
    touch = solver.contact(True)
    limits = 'ctrlrange="-1 1" ctrllimited="true" forcerange="-0.02 0.02" forcelimited="true"'
    return f"""
<mujoco model="zone_car">
  <option timestep="0.004" {solver.option()}/>
  {solver.custom()}
  <worldbody>
    {solver.floor()}
    <body name="agent" pos="0 0 0.1">
      <joint name="agent" type="free" damping="0"/>
      <site name="agent" type="sphere" size="0.032"/>
      <geom name="agent" type="box" size="0.1 0.1 0.05" density="5" {solver.contact(False)}/>
      <geom name="back_bumper" pos="0 0.15 0" size="0.1 0.01 0.05" {box}/>
      <geom name="back_connector" pos="0 0.125 0" size="0.01 0.025 0.03" {box}/>
      <geom name="front_bumper" pos="0 -0.165 0" size="0.05 0.01 0.05" {box}/>
      <geom name="front_connector" pos="0 -0.13 0.04" size="0.05 0.03 0.01" {box}/>
      <body name="left" pos="-0.1 0.1 -0.05">
        <joint name="left" type="hinge" axis="1 0 0" damping="0.001"/>
        <geom name="left" type="cylinder" size="0.05" fromto="-0.055 0 0 -0.005 0 0"
              density="5" {touch}/>
      </body>
      <body name="right" pos="0.1 0.1 -0.05">
        <joint name="right" type="hinge" axis="1 0 0" damping="0.001"/>
        <geom name="right" type="cylinder" size="0.05" fromto="0.005 0 0 0.055 0 0"
              density="5" {touch}/>
      </body>
      <body name="rear" pos="0 -0.1 -0.05">
        <joint name="rear" type="ball" damping="0.001"/>
        <geom name="rear" type="sphere" size="0.05" density="5" {touch}/>
      </body>
    </body>
  </worldbody>
  <sensor>
    <ballquat joint="rear" name="ballquat_rear"/>
    <ballangvel joint="rear" name="ballangvel_rear"/>
    {_imu_sensors()}
  </sensor>
  <actuator>
    <motor name="left" joint="left" gear="1" {limits}/>
    <motor name="right" joint="right" gear="1" {limits}/>
  </actuator>
</mujoco>"""


# Leg i: (hip direction in the torso plane, hip range, ankle axis, ankle range).
_ANT_LEGS = (
    ((1, 1), "-0.70 0.70", "-1 1 0", "0.52 1.74"),
    ((-1, 1), "-0.70 0.70", "1 1 0", "-1.74 -0.52"),
    ((-1, -1), "-0.70 0.70", "-1 1 0", "-1.74 -0.52"),
    ((1, -1), "-0.70 0.70", "1 1 0", "0.52 1.74"),
)
_ANT_GEOM_NAMES = (
    ("aux_1_geom", "left_leg_geom", "left_ankle_geom"),
    ("aux_2_geom", "right_leg_geom", "right_ankle_geom"),
    ("aux_3_geom", "back_leg_geom", "third_ankle_geom"),
    ("aux_4_geom", "rightback_leg_geom", "fourth_ankle_geom"),
)


def _ant_leg(i: int, solver: Solver) -> str:
    (sx, sy), hip_range, ankle_axis, ankle_range = _ANT_LEGS[i]
    aux, leg, foot = _ANT_GEOM_NAMES[i]
    arm, foot_len = 0.05, 0.1
    cap = 'type="capsule" size="0.02"'
    joint = 'armature="1" damping="1" limited="true"'
    return f"""
      <body name="leg_{i + 1}">
        <geom name="{aux}" fromto="0 0 0 {sx * arm} {sy * arm} 0" density="5" {cap} {solver.contact(False)}/>
        <body name="aux_{i + 1}" pos="{sx * arm} {sy * arm} 0">
          <joint name="hip_{i + 1}" type="hinge" axis="0 0 1" range="{hip_range}" {joint}/>
          <geom name="{leg}" fromto="0 0 0 {sx * arm} {sy * arm} 0" density="5" {cap} {solver.contact(True)}/>
          <body name="foot_{i + 1}" pos="{sx * arm} {sy * arm} 0">
            <joint name="ankle_{i + 1}" type="hinge" axis="{ankle_axis}" range="{ankle_range}" {joint}/>
            <geom name="{foot}" fromto="0 0 0 {sx * foot_len} {sy * foot_len} 0" density="50000"
                  {cap} {solver.contact(True)}/>
          </body>
        </body>
      </body>"""


def ant_xml(solver: Solver) -> str:
    """Ant: a spherical torso on a free joint with four two-joint legs, torque 150 x action
    (no force range), RK4 at 0.01 s. The feet are very dense (50000), as in the original."""
    legs = "".join(_ant_leg(i, solver) for i in range(4))
    motors = "".join(
        f'<motor name="{j}" joint="{j}" gear="150" ctrlrange="-1 1" ctrllimited="true"/>'
        for j in _ANT_JOINTS
    )
    joint_sensors = "".join(f'<jointpos joint="{j}" name="{j}"/>' for j in _ANT_JOINTS)
    vel_sensors = "".join(f'<jointvel joint="{j}" name="{j}_vel"/>' for j in _ANT_JOINTS)
    return f"""
<mujoco model="zone_ant">
  <compiler angle="radian" inertiafromgeom="true"/>
  <option timestep="0.01" integrator="RK4" {solver.option()}/>
  {solver.custom()}
  <worldbody>
    {solver.floor()}
    <body name="agent" pos="0 0 0.18">
      <joint name="root" type="free" armature="0" damping="0" limited="false" margin="0.01"/>
      <site name="agent" type="sphere" size="0.032" pos="0 0 -0.02"/>
      <geom name="torso_geom" type="sphere" size="0.0625" density="5" {solver.contact(True)}/>
      {legs}
    </body>
  </worldbody>
  <sensor>
    {_imu_sensors()}
    <framepos objtype="site" objname="agent" name="agent_pos"/>
    {joint_sensors}
    <frameangvel objtype="site" objname="agent" name="agent_qvel"/>
    {vel_sensors}
  </sensor>
  <actuator>{motors}</actuator>
</mujoco>"""


_XML = {"Point": point_xml, "Car": car_xml, "Ant": ant_xml}


def robot_xml(robot: str, solver: Solver = Solver()) -> str:
    """The MJCF text of `robot` with the given solver settings. Without `prune_contacts`
    every geom collides with every other (MuJoCo's default filtering), as in the original."""
    return _XML[robot](solver)


def load_model(robot: str, solver: Solver = Solver()) -> mujoco.MjModel:
    """Compile the MJCF of `robot` into a MuJoCo model."""
    return mujoco.MjModel.from_xml_string(robot_xml(robot, solver))


def start_height(robot: str, model: mujoco.MjModel, seconds: float = 1.0) -> float:
    """Height of the robot body at the episode start, metres.

    The original spawns every robot at `z_height`. For the Car that puts the wheels and the
    caster exactly on the floor (distance 0), where whether a contact exists at the first
    substep is decided by rounding: MuJoCo C (float64) finds none, MJX finds five, and the
    trajectories part. The Car therefore starts at the height where it rests under gravity:
    the body z after MuJoCo C runs `model` from the original's level pose at zero control for
    `seconds` (it is still to 1e-8 m/s after 0.4 s); its contacts then penetrate by ~1e-4 m.
    Point (height not a degree of freedom) and Ant (feet ~2 cm above the floor) keep `z_height`.
    """
    z_height = ROBOTS[robot].z_height
    if robot != "Car":
        return z_height
    data = mujoco.MjData(model)
    data.qpos[:] = np.array([0.0, 0.0, z_height, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    for _ in range(round(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    return float(data.qpos[2])
