"""The user-policy contract of the benchmark, and loading a policy by reference.

A policy is scored on a world through `Agent`, a record of the policy and of what it supports:

    Agent(policy, params=None, name="my-agent", worlds=("letter",), epsilon=False,
          multi_agent=False, coordinator_agent=None)

What the policy receives, per step and per episode (all JAX arrays; the evaluator `vmap`s it over
episodes and compiles it once per world):

- `obs`: the world's observation (`world.observation_space`, e.g. LetterWorld's
  `{"ap": uint8[V, V, L], "ego": uint8[V, V, 1]}`);
- `task_state`: a `tasks.TaskState`: the automaton state `task_state.q` (int32[]), the episode's
  compiled spec `task_state.spec` (an `automata.CompiledSpec`: `delta[S, A]`, `accepting[S, A]`,
  the one-step subgoals `subgoal_reach` / `subgoal_avoid` bool[S, G, A] with `subgoal_valid`
  bool[S, G], DeepLTL's candidate sequences `seq_pair` [S, C, L] read through
  `automata.tensors.pairs`, `alphabet` bool[A, P]), the step count `time`, `steps_in_q`, the last
  label `propositions` bool[P] and the world's state `env_state`;
- `key`: a fresh PRNG key; `params`: the agent's `params` unchanged (network weights, or None).

What it returns: the action (`world.action_space`: LetterWorld int32[], ZoneEnv float32[2]), or a
pair `(action, take_epsilon)` where `take_epsilon` (bool[] or an int32 epsilon slot) asks for an
epsilon transition of a limit-deterministic automaton (declare `epsilon=True`).

Memory: a pure function `policy(params, obs, task_state, key)` keeps none; a
`tasks.StatefulPolicy(init, apply, aborted=None)` keeps a carry for one episode
(`carry = init(params, obs, task_state, key)` at every episode start,
`output, carry = apply(params, obs, task_state, carry, key)` per step) and may give an episode up
through `aborted(carry)`.

What it supports: `worlds` (family names, `families.list_families()`; None: every world),
`epsilon` (returns epsilon choices), `multi_agent` (the policy acts on a multi-agent world as one
system: stacked observation and action), `coordinator_agent` (a single-agent
`(params, obs_i, subgoal_i, key) -> action_i` that the benchmark's central coordinator drives on
every agent of a multi-agent world, `tasks.coordinator`).

A policy is referred to by one string (`load`): `random`, `oracle` (LetterWorld's planner), a run
directory of `specrl-jax train` (method, world and options from its `config.json`), a results-store
cell (`LetterLTL0-v0/genz`, seed 1), or `package.module:factory`, where `factory(world)` returns an
`Agent` or a bare policy.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from specrl_jax import families
from specrl_jax.tasks.policy import StatefulPolicy

BUILT_IN = ("random", "oracle")


@dataclasses.dataclass(frozen=True)
class Agent:
    """A policy and what it supports (see the module docstring).

    Attributes:
        policy: `(params, obs, task_state, key) -> action | (action, take_epsilon)`, or a
            `StatefulPolicy`.
        params: given to the policy unchanged.
        name: the label of its column in reports.
        worlds: the world families it can act in (None: any).
        epsilon: whether it returns `(action, take_epsilon)` pairs.
        multi_agent: whether `policy` acts on a multi-agent world as one system.
        coordinator_agent: a single-agent policy for the coordinator on multi-agent worlds.
        params_per_seed: `params` has a leading axis, entry i serving evaluation seed `seeds[i]`.
        seeds: with `params_per_seed`, the evaluation seeds its entries serve.
    """

    policy: Callable[..., Any] | StatefulPolicy | None
    params: Any = None
    name: str = "policy"
    worlds: tuple[str, ...] | None = None
    epsilon: bool = False
    multi_agent: bool = False
    coordinator_agent: Callable[..., Any] | None = None
    params_per_seed: bool = False
    seeds: tuple[int, ...] | None = None

    def supports(self, family: str) -> bool:
        """Whether the agent can act in worlds of `family`."""
        if self.worlds is not None and family not in self.worlds:
            return False
        if family == families.MULTI_AGENT_ZONE.name:
            return self.multi_agent or self.coordinator_agent is not None
        return self.policy is not None


@dataclasses.dataclass(frozen=True)
class TrainedRun:
    """A baseline's trained parameters (a run directory or a store cell): evaluated through the
    method's own test-time policy, exactly as the training run evaluates itself."""

    method: str
    env_id: str
    params: Any  # leading seed axis
    env_options: dict[str, Any]
    method_options: dict[str, Any]
    source: str
    seeds: tuple[int, ...]  # the evaluation seed of each entry of `params`
    #: a store cell that runs another cell's parameters on every agent of a multi-agent world
    #: under the central coordinator (`benchmark.reproduce.evaluate_coordinator`)
    coordinator_cell: str | None = None

    @property
    def name(self) -> str:
        from specrl_jax.baselines.spec import get_method

        return get_method(self.method).title


def as_agent(obj: Any, what: str = "the policy") -> Agent:
    """An `Agent` from an `Agent`, a `StatefulPolicy` or a policy function; a TypeError that says
    what was given otherwise."""
    if isinstance(obj, Agent):
        return obj
    if isinstance(obj, StatefulPolicy) or callable(obj):
        return Agent(obj, name=getattr(obj, "__name__", "policy"))
    raise TypeError(
        f"{what} is a {type(obj).__name__}, not a policy: expected an Agent, a StatefulPolicy or "
        f"a function (params, obs, task_state, key) -> action")


def load_factory(ref: str) -> Callable[[Any], Any]:
    """`package.module:factory` -> the factory function, with clear errors."""
    module_name, _, attribute = ref.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"expected package.module:factory, got {ref!r}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ValueError(f"cannot import module {module_name!r} of policy {ref!r}: {err}") from None
    factory = module
    for part in attribute.split("."):
        if not hasattr(factory, part):
            names = sorted(n for n in vars(module) if not n.startswith("_"))
            raise ValueError(f"module {module_name!r} has no {attribute!r} (policy {ref!r}); it "
                             f"defines: {', '.join(names)}")
        factory = getattr(factory, part)
    if not callable(factory):
        raise TypeError(f"{ref!r} is a {type(factory).__name__}, not a factory function "
                        f"(world) -> Agent or policy")
    return factory


def load(ref: str, env_id: str, seed: int | None = None, world: Any = None
         ) -> Agent | TrainedRun:
    """The policy named by `ref` for the world `env_id` (see the module docstring).

    Args:
        ref: `random`, `oracle`, a run directory, a results-store cell, or `module:factory`.
        env_id: the world it is evaluated on; a trained run of another world is refused.
        seed: for a trained run, one of its seeds (1-based, its evaluation seed) instead of all.
        world: the world object given to a factory (default `make(env_id)`).
    """
    from specrl_jax.envs.registry import make

    if ref in BUILT_IN:
        world = make(env_id)[0] if world is None else world
        return _built_in(ref, world)
    path = Path(ref)
    if (path / "config.json").exists():
        return select_seed(_run_directory(path, env_id), seed)
    if ":" in ref and not path.exists():
        world = make(env_id)[0] if world is None else world
        return as_agent(load_factory(ref)(world), f"what {ref!r} returned")
    if path.exists():
        raise ValueError(f"{ref!r} is not a run directory of `specrl-jax train` (no config.json)")
    return select_seed(_store_cell(ref, env_id), seed)


def _built_in(name: str, world: Any) -> Agent:
    from specrl_jax.eval.planner import oracle_policy
    from specrl_jax.tasks.policy import random_policy

    if name == "random":
        return Agent(random_policy(world), name="random")
    return Agent(oracle_policy(world), name="oracle", worlds=(families.LETTER.name,))


def _same_world(trained_on: str, env_id: str, source: str) -> None:
    if trained_on.split(".")[0] != env_id.split(".")[0]:
        raise ValueError(f"{source} was trained on {trained_on}, not {env_id}; evaluate it with "
                         f"--env {trained_on}")


def _run_directory(path: Path, env_id: str) -> TrainedRun:
    from specrl_jax.benchmark import experiment

    config = json.loads((path / "config.json").read_text())
    _same_world(config["env"], env_id, str(path))
    if not (path / "params.msgpack").exists():
        raise ValueError(f"{path} holds no params.msgpack: its training has not finished")
    env_options = dict(config.get("env_options") or {})
    method_options = dict(config.get("method_options") or {})
    num_seeds = int(config.get("num_seeds", 1))
    params = experiment.load_params(config["method"], config["env"], path / "params.msgpack",
                                    num_seeds, env_options=env_options or None,
                                    method_options=method_options or None)
    return TrainedRun(config["method"], env_id, params, env_options, method_options, str(path),
                      tuple(range(1, num_seeds + 1)))


def _store_cell(name: str, env_id: str) -> TrainedRun:
    from specrl_jax.benchmark import grid
    from specrl_jax.benchmark.store import Store

    if name not in grid.BY_NAME:
        raise ValueError(f"unknown policy {name!r}; known policies: {', '.join(BUILT_IN)}; "
                         f"{name!r} is neither a run directory of `specrl-jax train` (no "
                         f"config.json) nor a results-store cell (`specrl-jax reproduce --list`) "
                         f"nor package.module:factory")
    store = Store()
    cell = store.trained_as(grid.cell(name))
    _same_world(cell.env_id, env_id, name)
    if not cell.trains:  # the coordinator over a single-agent cell's parameters
        if not store.params_path(cell.params_from).exists():
            raise ValueError(f"the results store holds no trained parameters for "
                             f"{cell.params_from}, which {name} runs{_why_none(cell)}")
        return TrainedRun(cell.method, env_id, store.load_params(cell.params_from), {}, {},
                          f"{name} (seed 1 of {cell.params_from})", (1,), coordinator_cell=name)
    if not store.params_path(cell).exists():
        raise ValueError(f"the results store holds no trained parameters for {name}"
                         f"{_why_none(cell)}; train a run with the cell's settings (`specrl-jax "
                         f"train --method {cell.method} --env {cell.env_id} ...`) and pass its "
                         "directory as the policy")
    return TrainedRun(cell.method, env_id, store.load_params(cell), dict(cell.env_options),
                      cell.options(), f"{name} (seed 1)", (1,))


def _why_none(cell: Any) -> str:
    """Why a store cell of this method ships no parameters ('' where it should have them)."""
    if cell.method != "gcrl":
        return ""
    return (" (GCRL-LTL's seed-1 parameters, 17-70 MB with its goal-conditioned value function, "
            "are not shipped with the package)")


def select_seed(run: TrainedRun, seed: int | None) -> TrainedRun:
    """`run` with only its evaluation seed `seed` (None: all of them)."""
    if seed is None:
        return run
    if seed not in run.seeds:
        raise ValueError(f"{run.source} holds seeds {', '.join(map(str, run.seeds))}; got --seed {seed}")
    i = run.seeds.index(seed)
    params = jax.tree.map(lambda x: x[i:i + 1], run.params)
    return dataclasses.replace(run, params=params, seeds=(seed,))


def with_seed_count(run: TrainedRun, count: int | None) -> TrainedRun:
    """`run` on evaluation seeds 1..count: its first `count` seeds, or its one kept seed (a
    store cell's seed 1) repeated under each; None keeps its own seeds."""
    if count is None:
        return run
    kept = len(run.seeds)
    if kept == 1:
        params = jax.tree.map(lambda x: np.repeat(x, count, axis=0), run.params)
    elif count <= kept:
        params = jax.tree.map(lambda x: x[:count], run.params)
    else:
        raise ValueError(f"{run.source} holds {kept} trained seeds; pass --seeds {kept} or fewer")
    return dataclasses.replace(run, params=params, seeds=tuple(range(1, count + 1)))


def check(agent: Agent, task: Any, params: Any, env_id: str) -> None:
    """Trace one reset and one policy step (shapes only) and check the output against the world:
    the action's shape and dtype, and epsilon pairs only from an agent that declares them."""
    from specrl_jax.tasks.policy import as_stateful

    policy = as_stateful(agent.policy)
    policy_params = agent.params
    if agent.params_per_seed:
        policy_params = jax.tree.map(lambda x: x[0], policy_params)

    def one_step(key):
        obs, state = task.reset(key, params, np.int32(0))
        carry = policy.init(policy_params, obs, state, key)
        return policy.apply(policy_params, obs, state, carry, key)[0]

    try:
        output = jax.eval_shape(one_step, jax.random.key(0))
    except Exception as err:  # the user's code failed on this world's inputs
        raise TypeError(f"policy {agent.name!r} failed on {env_id}'s observation and task state: "
                        f"{type(err).__name__}: {err}") from err
    if isinstance(output, tuple):
        if not agent.epsilon:
            raise TypeError(f"policy {agent.name!r} returned a pair (action, take_epsilon) but "
                            f"does not declare epsilon=True in its Agent")
        output = output[0]
    space = task.env.action_space
    shape, dtype = tuple(getattr(output, "shape", ())), np.dtype(getattr(output, "dtype", object))
    expected = np.dtype(space.dtype)
    if shape != tuple(space.shape) or dtype.kind != expected.kind:
        raise ValueError(f"policy {agent.name!r} returns actions of shape {shape} and dtype "
                         f"{dtype}; {env_id} takes shape {tuple(space.shape)} and dtype {expected}")


def policy_and_params(agent: Agent | TrainedRun, world: Any, env_params: Any) -> tuple[Any, Any]:
    """`(policy, parameters)` that run `agent` on `world` for `eval.evaluate`: a trained run's
    own test-time agent with its first seed's parameters, else the agent's policy and
    parameters."""
    if isinstance(agent, TrainedRun):
        from specrl_jax.benchmark.experiment import make_method, make_policy

        method = make_method(agent.method, world, env_params, None, agent.method_options)
        return (make_policy(agent.method, world, method, None),
                jax.tree.map(lambda x: x[0], agent.params))
    return agent.policy, agent.params


def evaluate(agent: Agent | TrainedRun, env_id: str, suites: Sequence[str], episodes: int,
             seeds: Sequence[int] = (1,), horizon: int | None = None,
             log: Callable[[str], None] = print) -> list:
    """Evaluate an agent or a trained run on `suites` of `env_id`: one compiled evaluator for
    every suite (`eval.suites.evaluate_suites`). A trained run evaluates each of its seeds with
    its own evaluation seed (`seeds` is then ignored). Returns one `SuiteResult` per suite."""
    from specrl_jax.benchmark import experiment
    from specrl_jax.envs.registry import make
    from specrl_jax.eval.suites import check_suites, evaluate_suites
    from specrl_jax.tasks import TaskEnv

    if isinstance(agent, TrainedRun) and agent.coordinator_cell is not None:
        from specrl_jax.benchmark import grid
        from specrl_jax.benchmark.reproduce import evaluate_coordinator

        if horizon is not None or agent.seeds != tuple(range(1, len(agent.seeds) + 1)):
            raise ValueError(f"{agent.source} runs each suite's own horizon on seeds 1..N")
        cell = dataclasses.replace(grid.cell(agent.coordinator_cell), seeds=len(agent.seeds),
                                   episodes=episodes)
        return evaluate_coordinator(cell, agent.params, suites, log)
    if isinstance(agent, TrainedRun):
        run = agent
        return experiment.evaluate(run.method, env_id, run.params, suites, episodes, log=log,
                                   horizon=horizon, env_options=run.env_options or None,
                                   method_options=run.method_options or None, seeds=run.seeds)
    world, env_params = make(env_id)
    family = families.of(world).name
    if not agent.supports(family):
        raise ValueError(f"policy {agent.name!r} does not declare support for {family} worlds "
                         f"(worlds={agent.worlds}, multi_agent={agent.multi_agent}, "
                         f"coordinator_agent={'set' if agent.coordinator_agent else 'None'})")
    check_suites(suites, world)  # before compiling any formula: which propositions are missing
    agent, world = _for_world(agent, world, suites)
    from specrl_jax import automata, specs

    first = specs.suite(suites[0])[:1]
    task = TaskEnv(world, automata.compile_suite(first, world.propositions, world.alphabet))
    check(agent, task, env_params, env_id)
    if agent.params_per_seed:
        seeds = agent.seeds or tuple(range(1, len(jax.tree.leaves(agent.params)[0]) + 1))
    return evaluate_suites(agent.policy, env_id, world, env_params, suites, episodes, seeds,
                           policy_params=agent.params, params_per_seed=agent.params_per_seed,
                           horizon=horizon, label=agent.name, log=log)


def _for_world(agent: Agent, world: Any, suites: Sequence[str]) -> tuple[Agent, Any]:
    """A multi-agent world as one system (`tasks.coordinator.SystemWorld`), with the coordinator
    over the agent's single-agent policy where it gives one."""
    if families.of(world).name != families.MULTI_AGENT_ZONE.name:
        return agent, world
    from specrl_jax import specs
    from specrl_jax.tasks.coordinator import SystemWorld, check_spec_agents, make_coordinator

    for name in suites:
        for formula in specs.suite(name):
            check_spec_agents(formula, world)
    if not agent.multi_agent:
        agent = dataclasses.replace(agent, policy=make_coordinator(agent.coordinator_agent, world))
    return agent, SystemWorld(world)

