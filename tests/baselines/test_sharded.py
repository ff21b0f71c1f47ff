"""Training and evaluation over every device: the env batch sharded over a `jax.sharding.Mesh`
on forced CPU devices, the same seed giving the same result on 1 or 2 devices, MuJoCo Warp stepped
on each device's own worlds, clear errors for
a batch that does not divide, and the multi-host path (`jax.distributed.initialize`) with two
processes on one machine."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
ROOT = HERE.parents[1]

#: a tiny PPO run on the chain world; the checksum of its parameters is compared across setups
CHAIN = """
import sys, jax, numpy as np
sys.path.insert(0, {here!r})
from chain import ChainMethod
from specrl_jax.baselines.ppo import PPOConfig, env_mesh, make_train
CFG = PPOConfig(num_envs=4, num_steps=8, total_timesteps=4 * 8 * 3, update_epochs=2,
                num_minibatches=2, loss="rco", target_kl=0.5)

def checksum(params):
    leaves = [np.asarray(x.addressable_data(0), np.float64) for x in jax.tree.leaves(params)]
    return [float(np.sum(l * np.arange(1, l.size + 1).reshape(l.shape))) for l in leaves]
"""

TWO_DEVICES = CHAIN + """
import json, tempfile
import jax.numpy as jnp
from specrl_jax.baselines import runs
from specrl_jax.benchmark import experiment
from specrl_jax.baselines.ppo import Trainer
from specrl_jax.eval.evaluate import make_evaluator
from specrl_jax.tasks import TaskEnv
sys.path.insert(0, {eval_dir!r})
from tiny_world import TinyWorld, reach_avoid_spec, recurrence_spec, stack_specs
out = {{}}
assert jax.device_count() == 2

# the whole training path of a run directory (two seeds side by side), 1 vs 2 devices
key = jax.random.key(3)
results = []
for mesh in (None, env_mesh()):
    with tempfile.TemporaryDirectory() as run_dir:
        runner = runs.train_in_run_dir(make_train(CFG, ChainMethod(), mesh), key, run_dir,
                                       chunk_updates=2, num_seeds=2, log=lambda line: None)
        results.append((runner, runs.read_metrics(run_dir)))
(plain, rows_plain), (sharded, rows_sharded) = results
out["sharded_devices"] = len(sharded.env_state[0].sharding.device_set)
pairs = zip(jax.tree.leaves(plain.params), jax.tree.leaves(sharded.params))
out["params_max_diff"] = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) for a, b in pairs)
successes = lambda rows: [r["successes"] for r in rows]
out["successes_equal"] = successes(rows_plain) == successes(rows_sharded)

# the one-call trainer on 2 devices: compared with the two-process run
runner, _ = jax.jit(make_train(CFG, ChainMethod(), env_mesh()))(jax.random.key(7))
out["checksum"] = checksum(runner.params)

# a batch that does not divide by the device count
try:
    Trainer(CFG.__class__(num_envs=3, num_steps=8, num_minibatches=1), ChainMethod(), env_mesh())
    out["indivisible"] = "no error"
except ValueError as err:
    out["indivisible"] = str(err)

# experiment.train (the pipeline of `specrl-jax train`) hands every local device to the trainer
class Built(Exception):
    pass

def capture(config, method, mesh=None):
    out["train_devices"] = None if mesh is None else int(mesh.size)
    raise Built

experiment.make_train = capture
try:
    experiment.train("genz", "LetterLTL0-v0", tempfile.mkdtemp(), {{"num_envs": 4, "num_steps": 8}},
                     map_bank=None, log=lambda line: None)
except Built:
    pass

# evaluation: 3 episodes (padded to 4) on both devices give the table of one device
world = TinyWorld()
task = TaskEnv(world, stack_specs([reach_avoid_spec(), recurrence_spec()]))
policy = lambda p, obs, state, key: jax.random.randint(key, (), 0, 4)
seeds = jnp.asarray([1, 2], jnp.uint32)
one = make_evaluator(policy, task, world.default_params, 3, devices=jax.devices()[:1])(None, seeds)
both = make_evaluator(policy, task, world.default_params, 3)(None, seeds)
out["eval_shape"] = list(both.success.shape)
pairs = zip(jax.tree.leaves(one), jax.tree.leaves(both))
out["eval_equal"] = all(np.array_equal(a, b) for a, b in pairs)
out["eval_successes"] = int(np.sum(both.success))

# MuJoCo Warp under the trainer's mesh: each device steps its own cars (`Trainer.per_device`), so
# the rollout has no gathers around Warp's foreign call
import warp
warp.config.optimization_level = 0
world, car_params, car, car_config = experiment.build(
    "genz", "CarLTL0-v0", {{"num_envs": 2, "num_steps": 1, "num_minibatches": 1, "update_epochs": 1}},
    None, jax.random.key(0), {{"physics": "warp"}})
trainer = make_train(car_config, car, env_mesh())
runner = jax.jit(trainer.init)(jax.random.key(1))
collect = jax.jit(lambda r: trainer.collect(r, jax.random.key(2))).lower(runner).compile()
traj = collect(runner)[2]
out["warp_gathers"] = collect.as_text().count("all-gather")
out["warp_devices"] = len(traj.reward.sharding.device_set)
out["warp_finite"] = bool(np.isfinite(np.asarray(traj.reward)).all()
                          and np.isfinite(np.asarray(jax.tree.leaves(traj.obs)[0])).all())
# and the evaluator: each device runs its own episodes
from specrl_jax.eval.evaluate import prepare_specs
car_task = TaskEnv(world, prepare_specs(world, ["F blue"])[0])
shape = world.action_space.shape
act = lambda p, obs, state, key: jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)
car_eval = make_evaluator(act, car_task, car_params, 2, horizon=3).lower(None, seeds).compile()
out["warp_eval_gathers"] = car_eval.as_text().count("all-gather")
# awaited: a Warp program still running when the process exits deadlocks XLA:CPU's shut-down
car_result = jax.block_until_ready(car_eval(None, seeds))
out["warp_eval_shape"] = list(car_result.success.shape)
print("RESULT " + json.dumps(out))
"""

WORKER = CHAIN + """
import json
process_id, port = int(sys.argv[1]), sys.argv[2]
jax.distributed.initialize(coordinator_address=f"localhost:{{port}}", num_processes=2,
                           process_id=process_id)
assert jax.process_count() == 2 and jax.device_count() == 2 and jax.local_device_count() == 1
runner, _ = jax.jit(make_train(CFG, ChainMethod(), env_mesh(jax.devices())))(jax.random.key(7))
print("RESULT " + json.dumps({{"checksum": checksum(runner.params),
                              "env_devices": len(runner.obs.sharding.device_set)}}))
"""


def _env(devices: int) -> dict[str, str]:
    env = {**os.environ, "JAX_PLATFORMS": "cpu",
           "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def _result(stdout: str) -> dict:
    import json

    line = next(line for line in stdout.splitlines() if line.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("localhost", 0))
        return sock.getsockname()[1]


def test_two_devices_and_two_hosts_train_and_evaluate_like_one():
    code = textwrap.dedent(TWO_DEVICES).format(here=str(HERE), eval_dir=str(HERE.parent / "eval"))
    single = subprocess.Popen([sys.executable, "-c", code], env=_env(2), text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    port = str(_free_port())
    worker = textwrap.dedent(WORKER).format(here=str(HERE))
    hosts = [subprocess.Popen([sys.executable, "-c", worker, str(i), port], env=_env(1), text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE) for i in range(2)]
    outs = [p.communicate(timeout=400) for p in (single, *hosts)]
    for proc, (stdout, stderr) in zip((single, *hosts), outs):
        assert proc.returncode == 0 and "RESULT" in stdout, stderr[-3000:]
    one_host, *two_hosts = (_result(stdout) for stdout, _ in outs)

    # sharded training: the env batch on both devices, the same run as on one device
    assert one_host["sharded_devices"] == 2
    assert one_host["params_max_diff"] < 1e-4
    assert one_host["successes_equal"]
    # the pipeline behind `specrl-jax train` shards over every local device
    assert one_host["train_devices"] == 2
    # a batch of 3 envs on 2 devices is refused with a way out
    assert "num_envs=3 is not divisible by the 2 devices" in one_host["indivisible"]
    assert "--num-envs 4" in one_host["indivisible"]
    # MuJoCo Warp's foreign call runs on each device's cars, not on cars gathered from both
    assert (one_host["warp_gathers"], one_host["warp_devices"]) == (0, 2)
    assert one_host["warp_finite"]
    assert one_host["warp_eval_gathers"] == 0 and one_host["warp_eval_shape"] == [2, 1, 2]
    # evaluation: padded and sharded, the same table as on one device
    assert one_host["eval_shape"] == [2, 2, 3] and one_host["eval_equal"]
    # two processes (jax.distributed.initialize, one device each) train as one process of two
    for host in two_hosts:
        assert host["env_devices"] == 2
        np.testing.assert_allclose(host["checksum"], one_host["checksum"], rtol=1e-4, atol=1e-4)
    np.testing.assert_array_equal(two_hosts[0]["checksum"], two_hosts[1]["checksum"])
