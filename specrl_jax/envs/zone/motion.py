"""Moving zones: where a level-1/2 zone is, as a function of the env step.

The original moves a zone through a mocap body tied to a free zone body by a soft weld
(solref: time constant 0.02 s, damping ratio 1.5). Before every physics substep the mocap is put
on the commanded circle `travel * (sin a, cos a)` about the layout centre, `a = angular_speed *
t * direction + phase` (t: simulated time before the substep), and the weld drags the zone after
it: the zone starts at its layout centre, reaches the circle after about 0.3 s and then trails
the command at a radius of 0.296 m.

On each planar axis the weld is a damped spring on the offset `p` from the layout centre,
`p'' = -(2 / tc) p' - (p - c) / (tc * dr)^2` (MuJoCo's soft-constraint dynamics at full
impedance, which holds while the zone is more than 1 mm from its target, as it always is once
it moves). The robot's integrator makes that a linear recurrence per substep, `s' = A s + B c`
with `s = (p, p')`, whose response to a circular command from rest has a closed form: a circle
plus two decaying modes. Each is a spiral term

    amplitude * decay**n * (sin, cos)(phase + direction * (shift + rate * n)),

n the substeps since the reset. A zone's offset is the sum of the terms, so `ZoneEnv` needs no
state for it and `reset_to` / `layout` describe the whole trajectory. `circle_motion` is the
single-term kinematic circle (no weld), kept as an option.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.envs.zone.models import ROBOTS

#: Zone motions a `ZoneConfig` may ask for.
MOTIONS = ("weld", "circle")
#: The original's weld `solref`: time constant (s) and damping ratio.
WELD_SOLREF = (0.02, 1.5)
#: The original's integrator per robot (MuJoCo 2.3.3; the RK4 is the classic one).
ORIGINAL_INTEGRATOR = {"Point": "euler", "Car": "euler", "Ant": "rk4"}


@dataclass(frozen=True)
class Motion:
    """Zone offsets from their layout centres as a sum of K spiral terms.

    Attributes:
        amplitude: K values, metres.
        decay: K values, factor per substep (1 for the circle).
        rate: K values, rad per substep, for direction +1.
        shift: K values, rad, for direction +1.
        substeps: physics substeps per env step.
    """

    amplitude: tuple[float, ...]
    decay: tuple[float, ...]
    rate: tuple[float, ...]
    shift: tuple[float, ...]
    substeps: int

    def offsets(self, time: jax.Array, direction: jax.Array, phase: jax.Array) -> jax.Array:
        """float32[Z, 2]: zone offsets from their layout centres, metres.

        Args:
            time: int32[], env steps since the reset.
            direction: float32[Z], +1 or -1 for moving zones, 0 for static ones.
            phase: float32[Z], rad, the command's angle at t = 0 (from +y towards +x).
        """
        n = time.astype(jnp.float32) * self.substeps
        rate, shift = jnp.asarray(self.rate, jnp.float32), jnp.asarray(self.shift, jnp.float32)
        angle = phase[:, None] + direction[:, None] * (shift + rate * n)  # [Z, K]
        decay = jnp.asarray(self.decay, jnp.float32) ** n
        radius = jnp.asarray(self.amplitude, jnp.float32) * decay
        xy = jnp.stack(
            [jnp.sum(radius * jnp.sin(angle), axis=-1), jnp.sum(radius * jnp.cos(angle), axis=-1)],
            axis=-1,
        )
        return jnp.abs(direction)[:, None] * xy


def circle_motion(travel: float, angular_speed: float, timestep: float, substeps: int) -> Motion:
    """The kinematic circle: the zone is on the commanded circle from t = 0."""
    return Motion((travel,), (1.0,), (angular_speed * timestep,), (0.0,), substeps)


def weld_recurrence(timestep: float, integrator: str) -> tuple[np.ndarray, np.ndarray]:
    """`(A float64[2, 2], B float64[2])`: one substep of the weld's spring on one axis,
    `(p, p') <- A (p, p') + B c` for a command `c` held over the substep."""
    timeconst, dampratio = WELD_SOLREF
    stiffness, damping = 1.0 / (timeconst * dampratio) ** 2, 2.0 / timeconst
    h = timestep
    if integrator == "euler":  # MuJoCo's semi-implicit Euler: velocity first, then position
        a = np.array(
            [[1 - h * h * stiffness, h - h * h * damping], [-h * stiffness, 1 - h * damping]]
        )
        return a, np.array([h * h * stiffness, h * stiffness])
    if integrator == "rk4":  # classic RK4 on a linear system with the command held
        flow = h * np.array([[0.0, 1.0], [-stiffness, -damping]])
        powers = [np.eye(2)]  # flow^k / k!
        for order in range(1, 5):
            powers.append(powers[-1] @ flow / order)
        held = sum(p / (k + 1) for k, p in enumerate(powers[:4]))  # I + F/2 + F^2/6 + F^3/24
        return sum(powers), h * held @ np.array([0.0, stiffness])
    raise ValueError(f"unknown integrator {integrator!r}; accepted: 'euler', 'rk4'")


def weld_motion(
    travel: float, angular_speed: float, timestep: float, integrator: str, substeps: int
) -> Motion:
    """The original's welded zone: the closed-form response, from rest at the layout centre,
    of the substep recurrence to the circular command (direction +1; -1 mirrors it)."""
    a, b = weld_recurrence(timestep, integrator)
    rate = angular_speed * timestep
    # Complex plane w = y + i x: the command travel * (sin, cos)(rate n) is travel * e^{i rate n}.
    # Steady response s_n = steady * e^{i rate n}.
    steady = np.linalg.solve(np.exp(1j * rate) * np.eye(2) - a, b * travel)
    eigenvalues, vectors = np.linalg.eig(a)
    if abs(eigenvalues[0] - eigenvalues[1]) < 1e-9 or np.max(np.abs(eigenvalues)) >= 1.0:
        raise ValueError(f"the weld recurrence has no distinct decaying modes: {eigenvalues}")
    # From rest: s_n = steady e^{i rate n} - A^n steady; position row of A^n steady per mode.
    modes = vectors[0] * np.linalg.solve(vectors, steady)
    terms = [(steady[0], np.exp(1j * rate))] + list(zip(-modes, eigenvalues.astype(complex)))
    return Motion(
        amplitude=tuple(float(abs(c)) for c, _ in terms),
        decay=tuple(float(abs(mu)) for _, mu in terms),
        rate=tuple(float(np.angle(mu)) for _, mu in terms),
        shift=tuple(float(np.angle(c)) for c, _ in terms),
        substeps=substeps,
    )


def make_motion(
    kind: str, robot: str, travel: float, angular_speed: float, substeps: int
) -> Motion:
    """The zone motion `kind` ("weld" or "circle") of `robot`'s world, on the original's
    timestep and integrator."""
    if kind not in MOTIONS:
        raise ValueError(f"unknown zone motion {kind!r}; accepted: {MOTIONS}")
    timestep = ROBOTS[robot].timestep
    if kind == "circle":
        return circle_motion(travel, angular_speed, timestep, substeps)
    return weld_motion(travel, angular_speed, timestep, ORIGINAL_INTEGRATOR[robot], substeps)


__all__ = ["MOTIONS", "Motion", "circle_motion", "make_motion", "weld_motion", "weld_recurrence"]
