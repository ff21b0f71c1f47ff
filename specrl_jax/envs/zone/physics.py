"""Physics backends of the Zone robots: MJX's JAX implementation, or MuJoCo Warp through MJX.

The env keeps only the MuJoCo state that the next step reads (`qpos`, `qvel`, `qacc_warmstart`)
and the outputs it observes; a full `mjx.Data` is rebuilt from a template at every step. This
keeps the env state small, and it is what the Warp backend needs: its contact buffer is one
array shared by all worlds of a batch (`naconmax` rows in all), which must not be selected
leaf-wise by auto-reset and must be sized by the number of worlds. `Physics.advance` therefore
runs under a custom batching rule that flattens any nesting of `vmap`s into one batch of worlds
and sizes the buffer to it.

Capsule-floor contacts (the Ant's legs and feet) get MuJoCo C's contact frame in both backends:
MJX-JAX while `Physics` traces (`contact_frame.py`), MuJoCo Warp process-wide from the first Warp
model with such contacts on (`warp_contact_frame.py`). A JAX model traced with MJX's own frame
(`c_contact_frame` False, for A/B comparisons) takes no lock, so tracing it on another thread
while a C-frame trace runs would see C's frame.
"""

from __future__ import annotations

import contextlib
import functools
import warnings

import jax
import jax.numpy as jnp
import mujoco
from flax import struct

from specrl_jax.envs import compiled
from specrl_jax.envs.zone import contact_frame, small_linalg
from specrl_jax.envs.zone.mjx_import import mjx

# isort: split
from mujoco.mjx._src.types import DisableBit

#: The physics backends `Physics` runs.
BACKENDS = ("jax", "warp")
#: Accepted values of `ZoneConfig.physics`: a backend, or "auto" (`resolve_physics`).
PHYSICS = ("auto", *BACKENDS)
#: Robots that "auto" steps with MuJoCo Warp on one NVIDIA GPU: MJX-JAX runs their contacts
#: 4-14x slower there (docs/results.md); the contact-free Point is faster on MJX-JAX.
WARP_ROBOTS = ("Car", "Ant")
SUBSTEPS = 10


@struct.dataclass
class PhysicsState:
    """What one world carries between env steps (dtype: MJX's, float32 unless x64).

    Attributes:
        qpos: [nq] generalised positions.
        qvel: [nv] generalised velocities.
        qacc_warmstart: [nv] the solver's warm start (MuJoCo carries it from step to step).
        agent_pos: [3] world position of the robot body (body 1), metres.
        agent_mat: [3, 3] its rotation (world <- body).
        sensordata: [nsensordata] the model's sensors after the last forward pass.
    """

    qpos: jax.Array
    qvel: jax.Array
    qacc_warmstart: jax.Array
    agent_pos: jax.Array
    agent_mat: jax.Array
    sensordata: jax.Array


def warp_available() -> bool:
    """Whether MJX can use MuJoCo Warp here (`warp-lang` importable)."""
    from mujoco.mjx import warp as mjx_warp

    return bool(mjx_warp.WARP_INSTALLED)


def _import_warp():
    """warp-lang, logging warnings and errors only: it logs its start-up and a line per kernel
    module it loads (dozens on a first step)."""
    import warp

    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)
    return warp


def _one_cuda_gpu() -> bool:
    """Whether JAX computes on exactly one device, an NVIDIA GPU, in float32 (MuJoCo Warp is
    float32 only; with `jax_enable_x64` MJX-JAX computes in float64)."""
    if jax.default_backend() != "gpu" or jax.device_count() != 1:
        return False
    if jax.dtypes.canonicalize_dtype(jnp.float64) == jnp.float64:
        return False
    return "nvidia" in jax.devices()[0].device_kind.lower()


def resolve_physics(physics: str, robot: str) -> str:
    """The backend that `ZoneConfig.physics` means on this machine.

    "auto" is "warp" for the robots in `WARP_ROBOTS` when JAX runs on one CUDA GPU in float32
    and warp-lang is installed, else "jax" (with a warning when only warp-lang is missing: the
    robot then steps several times slower). With several devices "auto" is "jax": MuJoCo Warp
    runs as a foreign call that XLA cannot split across devices (the trainer and the evaluator
    step each device's worlds apart, so "warp" given explicitly runs per device there); with
    `jax_enable_x64` too, as MuJoCo Warp is float32 only. "jax" and "warp" are kept as given.
    """
    if physics not in PHYSICS:
        raise ValueError(f"unknown physics backend {physics!r}; accepted: {PHYSICS}")
    if physics != "auto":
        return physics
    if robot not in WARP_ROBOTS or not _one_cuda_gpu():
        return "jax"
    if not warp_available():
        warnings.warn(f"the {robot} steps with MJX's JAX implementation on this GPU, several times "
                      "slower than with MuJoCo Warp, which needs warp-lang: "
                      "pip install 'specrl-jax[cuda]' (or warp-lang>=1.18)", stacklevel=2)
        return "jax"
    return "warp"


def _max_contacts(model: mujoco.MjModel) -> int:
    """Contacts one world can have: the slots MJX-JAX allocates for the model's pairs."""
    data = jax.eval_shape(mjx.make_data, mjx.put_model(model, impl="jax"))
    return int(data._impl.contact.dist.shape[0])


def _max_rows(model: mujoco.MjModel, contacts: int) -> int:
    """Constraint rows one world can have: pyramidal contacts (2 (condim - 1) rows, 1 for
    condim 1) plus one per limited joint."""
    condim = int(model.geom_condim.max()) if model.ngeom else 1
    per_contact = 1 if condim == 1 else 2 * (condim - 1)
    return max(1, contacts * per_contact + int(model.jnt_limited.sum()))


class Physics:
    """Steps one robot model: `init(qpos)` and `step(state, ctrl)` on one world (vmappable).

    Args:
        model: the robot's MuJoCo model.
        backend: "jax" (MJX's JAX implementation, any device) or "warp" (MuJoCo Warp
            through MJX: a CUDA GPU, or a CPU where warp-lang has its CPU compiler).
        substep_sensors: evaluate the model's sensors in every substep (MJX's `step` does);
            False (default) evaluates them only in the forward pass after the last substep,
            the only one the env reads; the dynamics are the same (backend "jax" only).
        unroll: how many substeps one iteration of the substep loop runs (`lax.scan`).
        small_cholesky: trace MJX's Cholesky factorisations and solves as written-out
            arithmetic (`small_linalg.small_cholesky`; backend "jax" only).

    Attributes:
        c_contact_frame: whether capsule-plane contacts get MuJoCo C's frame (a model with such
            pairs); with backend "jax", set it False before tracing for MJX's own frame (A/B
            comparisons only). With backend "warp" the frame is Warp's process-wide setting.

    Raises:
        RuntimeError: a model with capsule-plane contacts, and an MJX whose collider table (or
            whose MuJoCo Warp's, for backend "warp") is not laid out as `contact_frame`
            (`warp_contact_frame`) expects.
    """

    def __init__(
        self, model: mujoco.MjModel, backend: str = "jax", substep_sensors: bool = False,
        unroll: int = 1, small_cholesky: bool = False,
    ):
        if backend not in BACKENDS:
            raise ValueError(f"unknown physics backend {backend!r}; accepted: {BACKENDS}")
        if backend == "warp" and not warp_available():
            raise ValueError(
                "physics='warp' needs the warp-lang package (MuJoCo Warp through MJX); it is "
                "not importable here. Install warp-lang, or use physics='jax'"
            )
        self.backend = backend
        self.mj_model = model
        self._digest = compiled.model_digest(model)
        self.substep_sensors = substep_sensors
        if backend == "warp":
            _import_warp()
        self.model = mjx.put_model(model, impl=backend)
        self.unroll = unroll
        self.small_cholesky = small_cholesky and backend == "jax"
        if backend == "warp":
            # Warp prints a line per world and step when a cap is hit (line-search iterations,
            # contacts); across 65,536 worlds that floods the output. The caps still apply.
            self.model = self.model.replace(
                opt=self.model.opt.replace(_impl=self.model.opt._impl.replace(warn_overflow=0))
            )
        self.substep_model = self.model
        if backend == "jax" and not substep_sensors:
            flags = int(self.model.opt.disableflags) | int(DisableBit.SENSOR)
            self.substep_model = self.model.replace(
                opt=self.model.opt.replace(disableflags=DisableBit(flags))
            )
        # C's capsule-plane frame, for models that have such contacts (the Ant's, not
        # Point's or Car's); checked here so that an MJX without the expected layout fails now.
        self.c_contact_frame = contact_frame.plane_capsule_pairs(model) > 0
        if self.c_contact_frame and backend == "jax":
            contact_frame.check_mjx()
        elif self.c_contact_frame:
            from specrl_jax.envs.zone import warp_contact_frame

            warp_contact_frame.install()
        if backend == "jax":
            self._template = mjx.make_data(self.model)
            # MJX-JAX's forward skips the acceleration sensors of a model without any constraint
            # row (the pruned Point); they are then computed here, as MuJoCo C always does.
            no_rows = self._template._impl.efc_J.size == 0
            self._add_sensor_acc = model.nsensor > 0 and no_rows
        else:
            slots = _max_contacts(model)
            # Warp's collision functions need not make as few contacts per pair as MJX-JAX
            # allocates slots for; the buffer is shared by all worlds, so slack here is cheap.
            self.contacts_per_world = 2 * slots
            self.rows_per_world = _max_rows(model, slots)
            self._template = mjx.make_data(
                model, impl="warp", naconmax=self.contacts_per_world, njmax=self.rows_per_world
            )
            self._add_sensor_acc = False
            self._worlds = {n: self._warp_worlds(n) for n in (0, SUBSTEPS)}

    @property
    def dtype(self) -> jnp.dtype:
        return self._template.qpos.dtype

    def init(self, qpos: jax.Array) -> PhysicsState:
        """The state at rest at `qpos` ([nq]): zero velocity and control, one forward pass."""
        zeros = jnp.zeros(self.mj_model.nv, self.dtype)
        state = PhysicsState(
            qpos=jnp.asarray(qpos, self.dtype),
            qvel=zeros,
            qacc_warmstart=zeros,
            agent_pos=jnp.zeros(3, self.dtype),
            agent_mat=jnp.eye(3, dtype=self.dtype),
            sensordata=jnp.zeros(self.mj_model.nsensordata, self.dtype),
        )
        return self.advance(state, jnp.zeros(self.mj_model.nu, self.dtype), 0)

    def step(self, state: PhysicsState, ctrl: jax.Array) -> PhysicsState:
        """`SUBSTEPS` physics steps under `ctrl` ([nu], clipped to [-1, 1]), then the forward
        pass that the original runs before it reads the sensors."""
        return self.advance(state, jnp.clip(ctrl, -1.0, 1.0).astype(self.dtype), SUBSTEPS)

    def advance(self, state: PhysicsState, ctrl: jax.Array, substeps: int) -> PhysicsState:
        """`substeps` steps then a forward pass, one world (any number of `vmap`s around it).

        Traced once per model, options and `substeps` in a process (`compiled.ByKey`): an env's
        two resets (its own and the auto-reset's) and other envs of the same robot reuse it.
        """
        return _shared_advance(compiled.ByKey(self._trace_key(), self), state, ctrl, substeps)

    def _trace_key(self) -> tuple:
        """All that a trace of `advance` reads besides its arguments."""
        return (self._digest, self.backend, jnp.dtype(self.dtype).name, self.substep_sensors,
                self.unroll, self.small_cholesky, self.c_contact_frame)

    def _advance_traced(self, state: PhysicsState, ctrl: jax.Array, substeps: int) -> PhysicsState:
        if self.backend == "jax":
            with contextlib.ExitStack() as scope:
                if self.c_contact_frame:  # Warp's is installed at construction
                    scope.enter_context(contact_frame.c_contact_frame())
                if self.small_cholesky:
                    scope.enter_context(small_linalg.small_cholesky())
                return self._advance(self._template, state, ctrl, substeps)
        one = jax.tree.map(lambda x: x[None], (state, ctrl))
        worlds = self._worlds.get(substeps) or self._warp_worlds(substeps)
        return jax.tree.map(lambda x: x[0], worlds(*one))

    def _advance(
        self, template, state: PhysicsState, ctrl: jax.Array, substeps: int
    ) -> PhysicsState:
        data = template.replace(
            qpos=state.qpos, qvel=state.qvel, qacc_warmstart=state.qacc_warmstart, ctrl=ctrl
        )
        if substeps:  # `init` runs none: a scan of length 0 would still trace and compile a step
            data, _ = jax.lax.scan(
                lambda d, _: (mjx.step(self.substep_model, d), None), data, None,
                length=substeps, unroll=max(1, min(self.unroll, substeps)),
            )
        data = mjx.forward(self.model, data)
        if self._add_sensor_acc:
            data = mjx.sensor_acc(self.model, data)
        return PhysicsState(
            qpos=data.qpos,
            qvel=data.qvel,
            qacc_warmstart=data.qacc_warmstart,
            agent_pos=data.xpos[1],
            agent_mat=data.xmat[1],
            sensordata=data.sensordata,
        )

    def _warp_template(self, num_worlds: int):
        """The Warp data template with a contact buffer for `num_worlds` worlds."""
        impl = self._template._impl
        tiled = {
            f.name: jnp.tile(
                getattr(impl, f.name), (num_worlds,) + (1,) * (getattr(impl, f.name).ndim - 1)
            )
            for f in type(impl).fields()
            if f.name.startswith("contact__")
            and getattr(impl, f.name).shape[:1] == (impl.naconmax,)
        }
        naconmax = num_worlds * impl.naconmax
        impl = impl.replace(
            naconmax=naconmax, naccdmax=min(impl.naccdmax * num_worlds, naconmax), **tiled
        )
        return self._template.replace(_impl=impl)

    def _warp_worlds(self, substeps: int):
        """`worlds(state, ctrl)` over a leading axis of W worlds, with a batching rule that
        folds every enclosing `vmap` into that axis."""

        @jax.custom_batching.custom_vmap
        def worlds(state, ctrl):
            template = self._warp_template(ctrl.shape[0])
            return jax.vmap(lambda s, c: self._advance(template, s, c, substeps))(state, ctrl)

        @worlds.def_vmap
        def worlds_batched(axis_size, in_batched, state, ctrl):
            args = jax.tree.map(
                lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape),
                (state, ctrl),
                tuple(in_batched),
            )
            flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), args)
            out = worlds(*flat)
            out = jax.tree.map(lambda x: x.reshape((axis_size, -1) + x.shape[1:]), out)
            return out, jax.tree.map(lambda _: True, out)

        return worlds


@functools.partial(jax.jit, static_argnums=(0, 3))
def _shared_advance(
    physics: compiled.ByKey[Physics], state: PhysicsState, ctrl: jax.Array, substeps: int
) -> PhysicsState:
    return physics.value._advance_traced(state, ctrl, substeps)


__all__ = [
    "BACKENDS", "PHYSICS", "SUBSTEPS", "WARP_ROBOTS", "Physics", "PhysicsState", "resolve_physics",
    "warp_available",
]
