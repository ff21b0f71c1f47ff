"""One training job over two processes (`baselines.hosts`): two local CPU processes joined by
`jax.distributed` (one forced CPU device each, collectives over Gloo) train the chain world
through the run driver, are interrupted after the first chunk and resume from process 0's
checkpoint; only process 0 writes or prints; the result is that of one process over two
devices. Then `reproduce` runs a cell across both. The flags' checks are tested without JAX."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from flax import serialization

from specrl_jax.baselines import hosts, runs

HERE = Path(__file__).parent
ROOT = HERE.parents[1]

#: one process of the job (or, without a coordinator, the one-process reference on two devices)
WORKER = """
import json, os, sys
sys.path.insert(0, {here!r})
run_dir, store_dir, group = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
writes = []

def record_writes(event, args):  # every file this process creates, changes or removes
    if event == "open" and args[1] is not None and set(str(args[1])) & set("wax+"):
        writes.append(str(args[0]))
    elif event in ("os.rename", "os.remove", "os.mkdir"):
        writes.extend(str(a) for a in args[:1 + (event == "os.rename")])

sys.addaudithook(record_writes)
import jax
from chain import ChainMethod
from specrl_jax.baselines import hosts, runs
from specrl_jax.baselines.ppo import PPOConfig, env_mesh, make_train
from specrl_jax.benchmark import grid, reproduce
from specrl_jax.benchmark.store import Store

hosts.join(hosts.process_group(*group))
assert jax.device_count() == 2
CFG = PPOConfig(num_envs=4, num_steps=8, total_timesteps=4 * 8 * 3, update_epochs=2,
                num_minibatches=2, loss="rco", target_kl=0.5)

def train(run_dir):
    trainer = make_train(CFG, ChainMethod(), env_mesh())
    return runs.train_in_run_dir(trainer, jax.random.key(3), run_dir, chunk_updates=1,
                                 num_seeds=2, log=print)

if group[1] is not None:  # the job: interrupted after its first chunk, then run again
    chunks = runs.train_chunks

    def first_chunk_then_ctrl_c(*args, **kwargs):
        for item in chunks(*args, **kwargs):
            yield item
            raise KeyboardInterrupt

    runs.train_chunks = first_chunk_then_ctrl_c
    try:
        train(run_dir)
    except runs.TrainingInterrupted as err:
        print("INTERRUPTED", err.update)
    runs.train_chunks = chunks
runner = train(run_dir)
env_devices = len(runner.env_state[0].sharding.device_set)

# a results-store cell trained across the processes (evaluation stubbed: no suites)
def train_cell(cell, cell_run_dir, log, max_wall_s=None, seeds=None):
    cell_runner = train(cell_run_dir)
    return hosts.host_copy(cell_runner.params), {{"complete": True, "env_steps_per_seed": 96}}

states = reproduce.reproduce(cells=[grid.cell("LetterLTL0-v0/genz")], store=Store(store_dir),
                             train=train_cell, evaluate=lambda *args, **kw: [], trajectories=False)
print("RESULT " + json.dumps({{"process": jax.process_index(), "env_devices": env_devices,
                              "states": states, "writes": sorted(set(writes))}}))
"""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("localhost", 0))
        return sock.getsockname()[1]


def _start(run_dir: Path, store: Path, group: list, devices: int, **environ: str):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **environ,
           "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    code = textwrap.dedent(WORKER).format(here=str(HERE))
    return subprocess.Popen([sys.executable, "-c", code, str(run_dir), str(store),
                             json.dumps(group)], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _checkpoint(run_dir: Path) -> dict:
    return serialization.msgpack_restore((run_dir / "checkpoint.msgpack").read_bytes())


def test_two_processes_train_resume_and_write_as_one_process_of_two_devices(tmp_path):
    port = _free_port()
    job, one = tmp_path / "job", tmp_path / "one"
    procs = [
        # process 0 from the flags, process 1 with the coordinator from JAX's variable
        _start(job / "run", job / "store", [f"localhost:{port}", 2, 0], devices=1),
        _start(job / "run", job / "store", [None, 2, 1], devices=1,
               JAX_COORDINATOR_ADDRESS=f"localhost:{port}"),
        _start(one / "run", one / "store", [None, None, None], devices=2),
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    for proc, (stdout, stderr) in zip(procs, outs):
        assert proc.returncode == 0 and "RESULT" in stdout, stderr[-3000:]
    results = [json.loads(next(line for line in stdout.splitlines()
                               if line.startswith("RESULT "))[7:]) for stdout, _ in outs]
    (first, second, single), stdouts = results, [stdout for stdout, _ in outs]

    # one job: both processes, one device each, shard the env batch over both devices
    assert [first["process"], second["process"]] == [0, 1]
    assert first["env_devices"] == second["env_devices"] == single["env_devices"] == 2
    # interrupted after the first chunk, both resumed from process 0's checkpoint
    assert "INTERRUPTED 1" in stdouts[0] and "INTERRUPTED 1" in stdouts[1]
    assert "resumed at update 1" in stdouts[0]
    # process 0 alone writes (run directory, store) and prints progress
    written = {str(Path(p).resolve().relative_to(job)) for p in first["writes"]
               if Path(p).resolve().is_relative_to(job)}
    assert {"run/checkpoint.msgpack", "run/metrics.jsonl", "run/config.json"} <= written
    assert any(p.startswith("store/") and p.endswith("cell.json") for p in written)
    assert not [p for p in second["writes"] if Path(p).resolve().is_relative_to(tmp_path)]
    assert "update 3/3" in stdouts[0] and "LetterLTL0-v0/genz: partial" in stdouts[0]
    assert not [line for line in stdouts[1].splitlines()
                if ("update" in line or "genz" in line) and not line.startswith("RESULT")]
    # the same run as one process over two devices: Gloo's cross-process all-reduce sums in
    # another order than one process's, so floats agree to rounding, counts exactly
    job_state, one_state = _checkpoint(job / "run"), _checkpoint(one / "run")
    pairs = zip(_leaves(job_state["params"]), _leaves(one_state["params"]))
    assert max(float(np.max(np.abs(a - b))) for a, b in pairs) < 1e-5
    assert np.array_equal(job_state["update"], one_state["update"]) and job_state["update"][0] == 3
    rows = [[(r["update"], r["successes"]) for r in runs.read_metrics(d / "run")]
            for d in (job, one)]
    assert rows[0] == rows[1] and len(rows[0]) == 3
    # reproduce across both processes: the cell trained and recorded once
    assert first["states"] == second["states"] == {"LetterLTL0-v0/genz": "partial"}
    cell = json.loads(next((job / "store").glob("*/cell.json")).read_text())
    assert cell["training"]["complete"] and cell["cell"] == "LetterLTL0-v0/genz"


def _leaves(tree) -> list[np.ndarray]:
    if isinstance(tree, dict):
        return [leaf for key in sorted(tree) for leaf in _leaves(tree[key])]
    return [np.asarray(tree)]


@pytest.mark.parametrize("flags, environ, message", [
    ((None, 2, None), {}, "--num-processes needs its partner"),
    ((None, None, 1), {}, "--process-id needs its partner"),
    (("h:1", 2, 2), {}, "--process-id 2 is not below --num-processes 2"),
    ((None, 2, 0), {}, "need the coordinator's address"),
    (("h:1", None, None), {}, "no process count and index"),
    ((None, None, None), {"JAX_COORDINATOR_ADDRESS": "h:1"}, "no process count and index"),
    (("h", 2, 0), {}, "is not HOST:PORT"),
    (("h:99999", 2, 0), {}, "is not HOST:PORT"),
])
def test_inconsistent_process_flags_are_refused(flags, environ, message):
    with pytest.raises(ValueError, match=message):
        hosts.process_group(*flags, environ=environ)


def test_process_groups_from_flags_and_launchers():
    assert hosts.process_group(environ={}) is None
    assert hosts.process_group("h:1", 2, 1, environ={}) == hosts.ProcessGroup("h:1", 2, 1)
    assert hosts.process_group(None, 2, 1, environ={"JAX_COORDINATOR_ADDRESS": "h:2"}) == \
        hosts.ProcessGroup("h:2", 2, 1)
    slurm = {"SLURM_JOB_ID": "7", "SLURM_STEP_NODELIST": "n[1-2]", "SLURM_PROCID": "1",
             "SLURM_LOCALID": "0", "SLURM_NTASKS": "2"}
    assert hosts.process_group(environ=slurm) == hosts.ProcessGroup(None, None, None)
    assert hosts.process_group(environ={**slurm, "SLURM_NTASKS": "1"}) is None
    mpi = {"OMPI_MCA_orte_hnp_uri": "x", "OMPI_COMM_WORLD_SIZE": "4"}
    assert hosts.process_group("h:3", environ=mpi) == hosts.ProcessGroup("h:3", None, None)


def test_the_cli_refuses_inconsistent_process_flags(capsys):
    from specrl_jax import cli

    for command in (["train", "--method", "genz"], ["reproduce"]):
        code = cli.main([*command, "--coordinator", "localhost:1234", "--num-processes", "2",
                         "--process-id", "2"])
        assert code == 2
        assert "--process-id 2 is not below --num-processes 2" in capsys.readouterr().err
