"""The runnable examples under `examples/`, at tiny sizes."""

import importlib
from pathlib import Path

import jax
import numpy as np
import pytest

from specrl_jax import automata, specs
from specrl_jax.benchmark import bench
from specrl_jax.envs.registry import make
from specrl_jax.tasks import TaskEnv

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
IND = "letter/finite/ind"


@pytest.fixture
def tiny_network(monkeypatch):
    """The module `examples/letter_tiny_network.py` (it imports its teacher from examples/)."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    return importlib.import_module("letter_tiny_network")


def test_the_tiny_network_clones_its_teacher_and_scores(tiny_network):
    """Trained on 2,048 teacher states, the network picks the teacher's action on most of them
    (an untrained one does not); its factory gives the same params (a fixed seed), a pytree of
    arrays, a policy of valid actions, and the benchmark scores it on LetterWorld."""
    world, env_params = make("LetterLTL0-v0")
    sizes = {"steps": 400, "num_envs": 64, "num_steps": 32}
    params, views, actions = tiny_network.train(world, seed=0, **sizes)
    assert views.shape == (64 * 32, 2 * 7 * 7) and actions.shape == (64 * 32,)
    untrained = tiny_network.TinyNetwork().init(jax.random.key(0), views[:1])
    before = tiny_network.agreement(untrained, views, actions)
    after = tiny_network.agreement(params, views, actions)
    assert after > 0.8 and after > before + 0.3, (before, after)

    agent = tiny_network.make_agent(world, seed=0, **sizes)
    assert agent.name == "tiny-network" and agent.worlds == ("letter",)
    leaves = jax.tree.leaves(agent.params)
    assert leaves and all(isinstance(x, jax.Array) for x in leaves)
    assert sum(x.size for x in leaves) == 4356
    for a, b in zip(leaves, jax.tree.leaves(params), strict=True):
        np.testing.assert_array_equal(a, b)

    task = TaskEnv(world, automata.compile_suite(specs.suite(IND)[:1], world.propositions,
                                                 world.alphabet))
    key_reset, key_act = jax.random.split(jax.random.key(1))
    obs, state = task.reset(key_reset, env_params)  # op by op: cheaper than compiling a reset
    chosen = jax.jit(jax.vmap(agent.policy, (None, None, None, 0)))(
        agent.params, obs, state, jax.random.split(key_act, 64))
    assert chosen.shape == (64,) and chosen.dtype == np.int32
    assert ((chosen >= 0) & (chosen < 4)).all()

    report = bench.score(agent, worlds=("letter",), suites=[IND], seeds=1, episodes=2,
                         horizon=10, log=lambda line: None)
    (result,) = report.worlds[0].results
    assert result.method == "tiny-network"
    assert np.isfinite(result.result.per_seed()["eta_s"]).all()
