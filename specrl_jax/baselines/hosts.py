"""One training job over several processes (hosts): joining it (`jax.distributed`), and what the
run driver needs to stay one job: process 0 alone writes, every process reads, barriers, and the
whole value of an array sharded over every process's devices.

Every process runs the same program on the same settings; the env batch is sharded over
`jax.devices()`, the devices of every process. Files are written by process 0 on a filesystem
that every process reads (the run directory, checkpoints, the results store).

    group = hosts.process_group("host0:1234", num_processes=2, process_id=1)
    hosts.join(group)   # before any JAX computation
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping
from typing import Any

import jax
import numpy as np

#: the environment variable of `jax.distributed.initialize`'s coordinator address
COORDINATOR_ENV = "JAX_COORDINATOR_ADDRESS"


@dataclasses.dataclass(frozen=True)
class ProcessGroup:
    """`jax.distributed.initialize`'s arguments; a None is detected by JAX from the launcher
    (Slurm, Open MPI)."""

    coordinator: str | None  # "host:port" of process 0's coordinator service
    num_processes: int | None
    process_id: int | None


def launcher(environ: Mapping[str, str]) -> str | None:
    """The launcher of a job of several processes whose count and index JAX reads from the
    environment ("Slurm": `srun` of more than one task; "Open MPI": `mpirun -n N`, N > 1), or None."""
    if all(k in environ for k in ("SLURM_JOB_ID", "SLURM_STEP_NODELIST", "SLURM_PROCID",
                                  "SLURM_LOCALID")) and int(environ.get("SLURM_NTASKS", 1)) > 1:
        return "Slurm"
    if "OMPI_MCA_orte_hnp_uri" in environ and int(environ.get("OMPI_COMM_WORLD_SIZE", 1)) > 1:
        return "Open MPI"
    return None


def process_group(coordinator: str | None = None, num_processes: int | None = None,
                  process_id: int | None = None,
                  environ: Mapping[str, str] = os.environ) -> ProcessGroup | None:
    """The job this process joins, from the flags, else `JAX_COORDINATOR_ADDRESS` and a
    launcher's variables (`launcher`); None for a job of one process (no flag, no variable).

    Raises:
        ValueError: only one of `num_processes` and `process_id`, `process_id` not below
            `num_processes`, a count and index without a coordinator, a coordinator without a
            count and index outside a launcher, or a coordinator not of the form host:port.
    """
    coordinator = coordinator or environ.get(COORDINATOR_ENV) or None
    if (num_processes is None) != (process_id is None):
        given = "--num-processes" if process_id is None else "--process-id"
        raise ValueError(f"{given} needs its partner: give both --num-processes N and "
                         "--process-id I (0 <= I < N), or neither")
    if num_processes is None:
        where = launcher(environ)
        if coordinator is None and where is None:
            return None
        if where is None:
            raise ValueError(f"a coordinator ({coordinator}) but no process count and index: give "
                             "--num-processes N and --process-id I, or launch with Slurm (srun) "
                             "or Open MPI (mpirun), whose variables JAX reads")
        return ProcessGroup(coordinator and _checked_address(coordinator), None, None)
    if not 0 <= process_id < num_processes:
        raise ValueError(f"--process-id {process_id} is not below --num-processes "
                         f"{num_processes}: processes are numbered 0..{num_processes - 1}")
    if coordinator is None:
        raise ValueError("--num-processes and --process-id need the coordinator's address: "
                         f"--coordinator HOST:PORT (process 0's host) or {COORDINATOR_ENV}")
    return ProcessGroup(_checked_address(coordinator), num_processes, process_id)


def _checked_address(address: str) -> str:
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"coordinator address {address!r} is not HOST:PORT (e.g. host0:1234, "
                         "the host of process 0 and a free port)")
    return address


def join(group: ProcessGroup | None) -> None:
    """Join `group`'s job (`jax.distributed.initialize`; waits up to 5 minutes for the other
    processes); nothing for None. Call before any JAX computation.

    Raises:
        ValueError: JAX could not join (the backend already started, a detection failed).
    """
    if group is None:
        return
    try:
        jax.distributed.initialize(coordinator_address=group.coordinator,
                                   num_processes=group.num_processes, process_id=group.process_id)
    except (RuntimeError, ValueError) as err:
        raise ValueError(f"cannot join the job of several processes ({err})") from err


def joined() -> bool:
    """Whether `join` joined this process to a job (`jax.distributed`; starts no JAX backend)."""
    return jax.distributed.is_initialized()


def several() -> bool:
    """Whether this process is one of a job of more than one."""
    return joined() and jax.process_count() > 1


def is_writer() -> bool:
    """Whether this process writes the job's files (process 0; the only process of a job of one)."""
    return not joined() or jax.process_index() == 0


def writer_log(log: Callable[[str], None]) -> Callable[[str], None]:
    """`log` on process 0; on the other processes of a job, a log that drops its lines."""
    return log if is_writer() else _drop


def _drop(line: str) -> None:
    """A log that shows nothing."""


def barrier(name: str) -> None:
    """Wait until every process of the job reaches the barrier `name` (nothing in a job of one)."""
    if several():
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


def from_writer(value: Any) -> Any:
    """Process 0's `value` (a pytree of arrays) on every process: a decision taken by one clock
    (e.g. a wall-clock budget) stays one decision."""
    if not several():
        return value
    from jax.experimental import multihost_utils

    return multihost_utils.broadcast_one_to_all(value)


def host_copy(tree: Any) -> Any:
    """The whole value of every leaf of `tree` as numpy on this host; a leaf sharded over several
    processes' devices is gathered (a collective: call it on every process)."""
    if not several():
        return jax.device_get(tree)
    from jax.experimental import multihost_utils

    def copy(x: Any) -> Any:
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return jax.device_get(x)

    return jax.tree.map(copy, tree)


def put_like(value: np.ndarray, like: jax.Array) -> jax.Array:
    """`value` (the whole array, on every process) placed with `like`'s sharding, which may span
    several processes' devices."""
    return jax.make_array_from_callback(value.shape, like.sharding, lambda index: value[index])
