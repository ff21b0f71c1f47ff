"""Adding a world family is one record and its env module; adding a method is one package and one
`MethodSpec`. A tiny family and a tiny method, registered here only, go through the benchmark's
own training driver and evaluation unchanged."""

import dataclasses
import inspect
import time
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax import automata, families, specs
from specrl_jax.baselines import runs
from specrl_jax.baselines.ppo.networks import MLP, Categorical, PolicyOutput, critic
from specrl_jax.baselines.ppo.train import Method, PPOConfig, world_config
from specrl_jax.baselines.spec import MethodSpec, get_method, register_method, unregister_method
from specrl_jax.baselines.train_env import TaskTrainEnv
from specrl_jax.benchmark import experiment
from specrl_jax.envs import registry
from specrl_jax.tasks import StatefulPolicy, TaskEnv
from tests.eval.tiny_world import TinyConfig, TinyParams, TinyWorld

FORMULAS = ("F a", "F b", "F c")


class DotWorld(TinyWorld):
    family = "dot"
    obs_kinds = {"ap": "grid", "ego": "grid"}


DOT = families.WorldFamily(
    name="dot", title="Dot world", id_patterns=("DotLTL-*",), horizon=20,
    suites=("dot/finite/reach",),
    ppo={"num_envs": 4, "num_steps": 16, "num_minibatches": 2, "gamma": 0.9, "ent_coef": 0.01},
    rollout={"cpu": {"num_envs": 4, "num_steps": 16, "num_minibatches": 2},
             "gpu": {"num_envs": 64, "num_steps": 16, "num_minibatches": 2}},
)


class ReachNet(nn.Module):
    """Logits and value from the agent's view and the automaton state's one-hot."""

    @nn.compact
    def __call__(self, obs: dict) -> PolicyOutput:
        x = jnp.concatenate([obs["ap"].reshape(*obs["q"].shape[:-1], -1).astype(jnp.float32),
                             obs["q"]], axis=-1)
        hidden = MLP((32,), "tanh")(x)
        value = critic((32,), "tanh")(x)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(Categorical(nn.Dense(4)(hidden)), value, zeros, zeros)


def observe(obs: dict, state: Any) -> dict:
    return {"ap": obs["ap"], "q": jax.nn.one_hot(state.task.q, 4)}


@dataclasses.dataclass(frozen=True)
class Reach(Method):
    env: TaskTrainEnv
    network: nn.Module


def make_reach(world: Any, params: Any, family: str | None = None) -> Reach:
    bank = automata.compile_suite(FORMULAS, world.propositions, world.alphabet)

    def signals(info):
        reward = info["success"].astype(jnp.float32) - info["violation"].astype(jnp.float32)
        return reward, jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    return Reach(TaskTrainEnv(TaskEnv(world, bank, observe), params, signals), ReachNet())


def reach_config(family: str, **overrides: Any) -> PPOConfig:
    return world_config(family, {"update_epochs": 2}, **overrides)


def reach_policy(network: nn.Module, alphabet: Any, obs_kinds: Any,
                 deterministic: bool = True) -> StatefulPolicy:
    def init(params, obs, task_state, key):
        return ()

    def apply(params, obs, task_state, carry, key):
        out = network.apply(params, {"ap": obs["ap"][None], "q": jax.nn.one_hot(task_state.q, 4)[None]})
        action = out.pi.mode() if deterministic else out.pi.sample(key)
        return action[0], carry

    return StatefulPolicy(init, apply)


REACH = MethodSpec(name="reach", title="Reach", make_method=make_reach, ppo_config=reach_config,
                   make_policy=reach_policy, summarise=lambda row: row)


@pytest.fixture
def dot_and_reach():
    families.register_family(DOT)
    registry.register("DotLTL-v0", lambda **kw: (DotWorld(TinyConfig()), TinyParams()), "a test")
    specs.register_suite("dot/finite/reach", FORMULAS, ("a", "b", "c"), env_family="dot")
    register_method(REACH)
    yield
    unregister_method("reach")
    specs.unregister_suite("dot/finite/reach")
    registry.unregister("DotLTL-v0")
    families.unregister_family("dot")


def test_a_family_and_a_method_registered_in_a_test_train_and_evaluate(dot_and_reach, tmp_path):
    assert experiment.family("DotLTL-v0") == "dot"
    assert experiment.suites_for("DotLTL-v0") == ("dot/finite/reach",)
    assert get_method("reach") is REACH
    overrides = {**experiment.default_overrides("cpu", 4 * 16 * 3, "dot")}
    params, summary = experiment.train("reach", "DotLTL-v0", tmp_path / "run", overrides,
                                       num_seeds=2, map_bank=None, log=lambda _: None)
    assert summary["env_steps_per_seed"] == 4 * 16 * 3 and summary["ppo"]["gamma"] == 0.9
    assert jax.tree.leaves(params)[0].shape[0] == 2
    results = experiment.evaluate("reach", "DotLTL-v0", params, ["dot/finite/reach"], 4,
                                  log=lambda _: None)
    per_seed = results[0].result.per_seed()
    assert results[0].method == "Reach" and results[0].result.seeds == (1, 2)
    assert per_seed["eta_s"].shape == (2, len(FORMULAS))
    assert np.all((per_seed["eta_s"] >= 0) & (per_seed["eta_s"] <= 1))
    loaded = experiment.load_params("reach", "DotLTL-v0", tmp_path / "run" / "params.msgpack", 2)
    assert jax.tree.all(jax.tree.map(np.array_equal, loaded, jax.device_get(params)))


def test_registries_refuse_clashes_and_unknown_names(dot_and_reach):
    with pytest.raises(ValueError, match="already registered"):
        families.register_family(DOT)
    with pytest.raises(ValueError, match="already registered"):
        register_method(REACH)
    with pytest.raises(ValueError, match="unknown world family 'dott'. Did you mean 'dot'"):
        families.get("dott")
    with pytest.raises(ValueError, match="unknown method 'reech'; accepted: .*reach"):
        get_method("reech")
    with pytest.raises(ValueError, match="Reach has no option 'width'; accepted: "):
        REACH.check_options({"width": 3})


@pytest.mark.parametrize("name", ["genz", "deepltl", "ltl2action", "gcrl", "rad"])
def test_each_baseline_declares_the_options_its_make_method_takes(name):
    spec = get_method(name)
    assert spec.options == tuple(list(inspect.signature(spec.make_method).parameters)[3:])
    assert spec.name == name and spec.title


def test_the_set_up_before_training_counts_in_the_wall_clock_budget_and_is_kept(dot_and_reach, tmp_path, monkeypatch):
    kept = []

    def slow_preparation(method, key, config, log, saved):
        time.sleep(0.5)  # e.g. GCRL-LTL's direction primitives
        kept.append(saved)
        return method

    given = []
    train_in_run_dir = runs.train_in_run_dir

    def recording(*args, max_wall_s=None, **kwargs):
        given.append(max_wall_s)
        return train_in_run_dir(*args, max_wall_s=max_wall_s, **kwargs)

    monkeypatch.setattr(runs, "train_in_run_dir", recording)
    unregister_method("reach")
    register_method(dataclasses.replace(REACH, prepare_training=slow_preparation))
    overrides = {**experiment.default_overrides("cpu", 4 * 16 * 3, "dot")}
    experiment.train("reach", "DotLTL-v0", tmp_path / "run", overrides, map_bank=None,
                     log=lambda _: None, max_wall_s=100.0)
    assert len(given) == 1 and given[0] <= 99.5
    assert kept == [tmp_path / "run" / experiment.PREPARED]  # the phase's result, for a resume


def test_the_phase_after_training_waits_for_the_last_update(dot_and_reach, tmp_path):
    finished = []

    def finish(method, params, key, config, log, program_key, first_seed):
        finished.append(config.num_updates)  # e.g. GCRL-LTL's value functions
        return {"policy": params, "extra": np.zeros(1)}

    unregister_method("reach")
    register_method(dataclasses.replace(REACH, finish_training=finish))
    overrides = {**experiment.default_overrides("cpu", 4 * 16 * 3, "dot")}
    run = tmp_path / "run"
    params, summary = experiment.train("reach", "DotLTL-v0", run, overrides, map_bank=None,
                                       log=lambda _: None, max_wall_s=0.0)
    assert not summary["complete"] and finished == [] and "extra" not in params
    assert not (run / "params.msgpack").exists()  # the policy alone is not the method's params
    params, summary = experiment.train("reach", "DotLTL-v0", run, overrides, map_bank=None,
                                       log=lambda _: None)
    assert summary["complete"] and len(finished) == 1 and "extra" in params
    assert (run / "params.msgpack").exists()
