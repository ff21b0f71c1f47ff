"""The multi-agent coordinator (`tasks.coordinator`): the split of a joint subgoal by agent on
hand-built system specs (independent, cooperative "both at once", mixed, persistence with its
epsilon jump), agreement with a plain-Python transcription of the split rule, clear errors for
specs naming agents the world lacks, the system view of per-agent termination, and one
coordinated episode through the ordinary task loop and evaluator."""

from __future__ import annotations

import itertools
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import specrl_jax
from specrl_jax import automata
from specrl_jax.baselines import gcrl
from specrl_jax.baselines.ppo.networks import DiagGaussian, PolicyOutput
from specrl_jax.eval.evaluate import evaluate, record_episodes
from specrl_jax.tasks import TaskEnv
from specrl_jax.tasks.coordinator import (
    AgentSubgoal,
    SystemWorld,
    agent_codes,
    check_spec_agents,
    compile_system_specs,
    current_subgoal,
    make_coordinator,
    split_subgoal,
)


@pytest.fixture(scope="module")
def world():
    env, params = specrl_jax.make("PointLTL0MA2-v0")
    alphabet = np.asarray(env.alphabet)
    agent_alphabet = np.asarray(env.world.alphabet)
    codes = jnp.asarray(agent_codes(alphabet, agent_alphabet, env.num_agents))
    return env, params, alphabet, agent_alphabet, codes


def _symbol(env, alphabet, *names):
    row = np.array([p in names for p in env.propositions])
    return int(np.nonzero((alphabet == row).all(1))[0][0])


def _parts(env, goal):
    """Per agent: (active, reach colours, avoid colours), as sets of names."""
    cols = env.colour_propositions
    names = lambda mask: {c for c, on in zip(cols, np.asarray(mask)) if on}
    return [(bool(goal.agents.active[i]), names(goal.agents.reach[i]), names(goal.agents.avoid[i]))
            for i in range(env.num_agents)]


def _walk(world, formula, labels):
    """The subgoal at the initial state, then after each joint label (taking the epsilon jump
    where the coordinator takes it)."""
    env, _, alphabet, agent_alphabet, codes = world
    spec = automata.compile_spec(formula, env.propositions, alphabet=alphabet)
    q, goals = spec.init, []
    for names in [()] + labels:
        symbol = _symbol(env, alphabet, *names)
        goal = current_subgoal(spec, q, jnp.int32(symbol), codes, agent_alphabet)
        if names:
            jump = bool(goal.take_epsilon)
            q = spec.epsilon[q, goal.epsilon_slot] if jump else spec.delta[q, symbol]
            goal = current_subgoal(spec, q, jnp.int32(symbol), codes, agent_alphabet)
        goals.append(goal)
    return goals


def test_independent_spec_gives_each_agent_its_own_task(world):
    env = world[0]
    goals = _walk(world, "(!yellow_0 U blue_0) & (!green_1 U magenta_1)", [("blue_0",)])
    assert _parts(env, goals[0]) == [(True, {"blue"}, {"yellow"}), (True, {"magenta"}, {"green"})]
    # agent 0 done: it holds still, agent 1 keeps its task
    assert _parts(env, goals[1]) == [(False, set(), set()), (True, {"magenta"}, {"green"})]
    assert not bool(goals[1].take_epsilon) and not bool(goals[1].stuck)


def test_cooperative_spec_asks_both_at_once(world):
    env = world[0]
    goals = _walk(world, "!(magenta_0 | magenta_1) U (blue_0 & blue_1)", [("blue_0",)])
    both = [(True, {"blue"}, {"magenta"})] * 2
    assert _parts(env, goals[0]) == both
    assert _parts(env, goals[1]) == both  # one agent there is not progress: both still go


def test_mixed_spec_alternates_individual_and_joint_parts(world):
    env = world[0]
    formula = "!magenta_0 U (blue_0 & F(magenta_1 & F(blue_0 & blue_1)))"
    goals = _walk(world, formula, [("blue_0",), ("magenta_1",)])
    # shortest: blue_0 and magenta_1 together (F includes now), then both at blue
    assert _parts(env, goals[0]) == [(True, {"blue"}, {"magenta"}), (True, {"magenta"}, set())]
    assert _parts(env, goals[1]) == [(False, set(), set()), (True, {"magenta"}, set())]
    assert _parts(env, goals[2]) == [(True, {"blue"}, set()), (True, {"blue"}, set())]


def test_an_agent_free_of_the_subgoal_is_idle_but_keeps_its_avoid_set(world):
    env = world[0]
    (goal,) = _walk(world, "F yellow_0 & G !green_1", [])
    assert _parts(env, goal) == [(True, {"yellow"}, set()), (False, set(), {"green"})]


def test_persistence_takes_the_epsilon_jump_only_at_the_joint_target(world):
    env = world[0]
    formula = "F G(yellow_0 & magenta_1) & G !(green_0 | blue_1)"
    spec = automata.compile_spec(formula, env.propositions, alphabet=world[2])
    assert bool(automata.has_epsilon(spec, spec.init))
    start, there_early, after = _walk(world, formula, [("yellow_0",), ("yellow_0", "magenta_1")])
    assert not bool(start.take_epsilon) and int(start.epsilon_slot) == -1
    assert _parts(env, start) == [(True, {"yellow"}, {"green"}), (True, {"magenta"}, {"blue"})]
    assert not bool(there_early.take_epsilon)  # only agent 0 there: jumping now would violate
    # after the jump: stay, every other label avoided, leaving the zone too (the empty label)
    assert _parts(env, after) == [(True, {"yellow"}, {"blue", "green", "magenta"}),
                                  (True, {"magenta"}, {"blue", "green", "yellow"})]
    assert bool(after.agents.avoid_symbols[:, 0].all())
    both = jnp.int32(_symbol(env, world[2], "yellow_0", "magenta_1"))
    goal = current_subgoal(spec, spec.init, both, world[4], world[3])
    assert bool(goal.take_epsilon) and int(goal.epsilon_slot) == 0


def _split_reference(reach, avoid, joint, agent_alphabet, num_agents):
    """The split rule transcribed on Python lists (module docstring of tasks.coordinator)."""
    num_props = agent_alphabet.shape[1]
    labels = [tuple(row) for row in agent_alphabet.tolist()]
    parts = [[labels.index(tuple(row[i * num_props:(i + 1) * num_props]))
              for i in range(num_agents)] for row in joint.tolist()]
    empty = labels.index(tuple([False] * num_props))
    chosen = [a for a in range(len(parts)) if reach[a]]
    if not chosen:
        target = [empty] * num_agents
    else:
        best = min(chosen, key=lambda a: (sum(sum(agent_alphabet[c]) for c in parts[a]), a))
        target = parts[best]
    out = []
    for i in range(num_agents):
        active = target[i] != empty
        avoid_i = set()
        for a in range(len(parts)):
            others = all(parts[a][j] in (empty, target[j]) for j in range(num_agents) if j != i)
            if avoid[a] and others and not (active and parts[a][i] == target[i]):
                avoid_i.add(parts[a][i])
        out.append((active, {target[i]} if active else set(), avoid_i))
    return out


@pytest.mark.parametrize("env_id", ["PointLTL0MA2-v0", "PointLTL0MA3-v0"])
def test_split_matches_a_python_transcription_on_random_pairs(env_id):
    env, _ = specrl_jax.make(env_id)
    joint, agent_alphabet = np.asarray(env.alphabet), np.asarray(env.world.alphabet)
    codes = jnp.asarray(agent_codes(joint, agent_alphabet, env.num_agents))
    split = jax.jit(jax.vmap(lambda r, a: split_subgoal(r, a, codes, agent_alphabet)))
    rng = np.random.default_rng(0)
    num = 24
    density = rng.choice([0.02, 0.1, 0.5], size=(num, 1))
    reach = rng.random((num, joint.shape[0])) < density
    reach[0] = False  # an empty reach set: nobody acts
    avoid = (rng.random((num, joint.shape[0])) < 0.3) & ~reach
    goals = split(jnp.asarray(reach), jnp.asarray(avoid))
    for k in range(num):
        expected = _split_reference(reach[k], avoid[k], joint, agent_alphabet, env.num_agents)
        for i, (active, reach_i, avoid_i) in enumerate(expected):
            assert bool(goals.active[k, i]) == active
            assert set(np.nonzero(np.asarray(goals.reach_symbols[k, i]))[0]) == reach_i
            assert set(np.nonzero(np.asarray(goals.avoid_symbols[k, i]))[0]) == avoid_i
            props = np.any(np.asarray(goals.avoid_symbols[k, i])[:, None] & agent_alphabet, 0)
            np.testing.assert_array_equal(goals.avoid[k, i], props)


def test_agent_codes_rebuild_the_joint_alphabet(world):
    _env, _, alphabet, agent_alphabet, codes = world
    rebuilt = np.concatenate([agent_alphabet[np.asarray(codes)[:, i]] for i in range(2)], axis=1)
    np.testing.assert_array_equal(rebuilt, alphabet)
    pairs = sorted(map(tuple, np.asarray(codes).tolist()))
    assert pairs == list(itertools.product(range(5), repeat=2))
    with pytest.raises(ValueError, match="3 agents x 4"):
        agent_codes(alphabet, agent_alphabet, 3)


def test_specs_naming_missing_agents_are_refused(world):
    env = world[0]
    with pytest.raises(ValueError, match=r"blue_2 \(agent 2\).*2 agents, agent_0, agent_1"):
        check_spec_agents("F blue_0 & F blue_2", env)
    with pytest.raises(ValueError, match="agent 7"):
        compile_system_specs(["G !green_1", "F(yellow_7 & blue_0)"], env)
    with pytest.raises(ValueError, match=r"unknown propositions \['red_0'\]"):
        check_spec_agents("F red_0", env)
    check_spec_agents("F blue_1", env)  # a known agent passes
    single, _ = specrl_jax.make("PointLTL0-v0")
    with pytest.raises(TypeError, match="multi-agent world"):
        make_coordinator(lambda p, o, g, k: jnp.zeros(2), single)


class _TwoAgents:
    """A stand-in world whose step reports given per-agent flags."""

    default_params = None

    def __init__(self, terminated, time):
        self.flags, self.time = jnp.asarray(terminated), time

    def step(self, key, state, action, params):
        state = type("S", (), {"time": jnp.int32(self.time)})()
        return {}, state, jnp.ones(2), self.flags, ~self.flags, {}


def test_system_world_ends_on_any_agent_and_truncates_at_the_horizon_only():
    params = type("P", (), {"max_steps": 10})()
    cases = [([False, False], 5, False, False), ([False, True], 5, True, False),
             ([False, False], 10, False, True), ([True, True], 10, True, False)]
    for flags, time, terminated, truncated in cases:
        out = SystemWorld(_TwoAgents(flags, time)).step(None, None, None, params)
        assert out[3].shape == () and bool(out[3]) == terminated
        assert out[4].shape == () and bool(out[4]) == truncated
        assert float(out[2]) == 2.0


COLOURS = ("blue", "green", "magenta", "yellow")


@struct.dataclass
class _DotParams:
    max_steps: int = 40


@struct.dataclass
class _DotState:
    xy: jax.Array  # float32[N, 2]
    time: jax.Array


class _DotWorld:
    """Two point agents moving at most 0.25 per step from the origin among four zones of radius
    0.3 (one per colour, 2 m out on the axes); `ap[i]` holds agent i's offset to each zone."""

    colour_propositions = COLOURS
    centres = np.asarray([[2.0, 0.0], [0.0, 2.0], [-2.0, 0.0], [0.0, -2.0]], np.float32)
    agents, num_agents = ("agent_0", "agent_1"), 2
    propositions = tuple(f"{c}_{i}" for i in range(2) for c in COLOURS)
    num_propositions = 8
    obs_kinds: ClassVar[dict[str, str]] = {"ap": "vector", "ego": "vector", "others": "vector"}
    default_params = _DotParams()
    action_space = type("Space", (), {"shape": (2, 2)})()
    world = type("One", (), {"alphabet": automata.zero_or_one(4)})()
    alphabet = automata.product(automata.zero_or_one(4), automata.zero_or_one(4))

    def _obs(self, xy):
        offsets = self.centres[None] - xy[:, None]
        return {"ap": offsets, "ego": xy, "others": xy[::-1]}

    def reset(self, key, params):
        xy = jnp.zeros((2, 2))
        return self._obs(xy), _DotState(xy, jnp.int32(0))

    def step(self, key, state, action, params):
        norm = jnp.linalg.norm(action, axis=-1, keepdims=True)
        xy = state.xy + action * jnp.minimum(1.0, 0.25 / jnp.maximum(norm, 1e-9))
        labels = jnp.linalg.norm(self.centres[None] - xy[:, None], axis=-1) <= 0.3
        done = jnp.zeros(2, bool)
        state = _DotState(xy, state.time + 1)
        return self._obs(xy), state, jnp.zeros(2), done, done, {"propositions": labels.reshape(-1)}


def _towards_reach(agent_params, obs, goal, key):
    """An oracle agent: straight at the zone of its reach colour (zero without one)."""
    return jnp.sum(jnp.where(goal.reach[:, None], obs["ap"], 0.0), axis=0)


def test_oracle_agents_under_the_coordinator_solve_system_specs_through_evaluate():
    dots = _DotWorld()
    world = SystemWorld(dots)
    formulas = [
        "(!yellow_0 U blue_0) & (!green_1 U magenta_1)",  # independent: 7 steps each, in parallel
        "!(magenta_0 | magenta_1) U ((blue_0 & blue_1) & F(green_0 & green_1))",  # cooperative
        "F yellow_0 & F(blue_0 & F green_1)",  # mixed: one agent's leg, one joint leg
        "G F blue_0 & G F green_1 & G !(yellow_0 | magenta_1)",  # recurrence (infinite)
    ]
    policy = make_coordinator(_towards_reach, dots)
    result = evaluate(policy, (world, world.default_params), formulas, seeds=[0],
                      episodes_per_seed=2)
    table = result.table
    np.testing.assert_array_equal(table.success[0, :3], True)
    assert not table.violation.any() and not table.aborted.any()
    # blue from the origin: 1.7 m to the zone's edge at 0.25 m/step; from blue to green: 2.4 m
    np.testing.assert_array_equal(table.steps[0, 0], 7)
    np.testing.assert_array_equal(table.steps[0, 1], 7 + 10)
    np.testing.assert_array_equal(table.steps[0, 2], 7 + 10)  # two legs, one of them joint
    # recurrence: both agents in their zones from step 7 on, every later step accepting
    np.testing.assert_array_equal(table.steps[0, 3], 40)
    np.testing.assert_array_equal(table.num_accepting[0, 3], 40 - 7 + 1)


def test_agents_without_a_part_hold_still():
    dots = _DotWorld()
    task = TaskEnv(SystemWorld(dots), compile_system_specs(["F yellow_0 & G !green_1"], dots))
    moved = lambda agent_params, obs, goal, key: jnp.ones(2)  # every agent asked to move
    states, alive = record_episodes(make_coordinator(moved, dots), task, dots.default_params,
                                    jax.random.split(jax.random.key(0), 1),
                                    jnp.zeros(1, jnp.int32), horizon=5)
    xy = np.asarray(states.env_state.xy[0])  # [T + 1, N, 2]
    assert bool(alive[0].all())
    np.testing.assert_allclose(xy[-1, 0], [5 * 0.25 / np.sqrt(2)] * 2, rtol=1e-5)
    np.testing.assert_array_equal(xy[:, 1], 0.0)


def test_the_coordinator_traces_through_the_task_loop_on_the_mjx_world(world):
    env, params, *_ = world
    task = TaskEnv(SystemWorld(env), compile_system_specs(["F(blue_0 & blue_1)"], env))
    seen = []

    def agent_policy(agent_params, obs, goal, key):
        seen.append(jax.tree.map(jnp.shape, obs))
        return jnp.zeros(2)

    policy = make_coordinator(agent_policy, env)

    def one_step(key):  # shapes only: no MJX compile on the CPU
        obs, state = task.reset(key, params)
        carry = policy.init(None, obs, state, key)
        (action, slot), carry = policy.apply(None, obs, state, carry, key)
        out = task.step_task(key, state, action, params, slot)
        return action, out[3], out[4], policy.aborted(carry)

    action, terminated, truncated, aborted = jax.eval_shape(one_step, jax.random.key(0))
    assert seen[0] == {"ap": (4, 16), "ego": (16,)}  # one agent's single-agent observation
    assert (action.shape, action.dtype) == ((2, 2), jnp.float32)
    assert terminated.shape == truncated.shape == aborted.shape == ()


class _GoalNet:
    """A hand-made GCRL network for the dot world (per agent: `ap` offsets, then `ego`): for
    goal g the mean action a quarter of the offset to zone g, the value `1 - 0.1 * distance`."""

    continuous = True
    primitive_sensors = 0

    def apply(self, params, obs):
        offsets = obs.parts["vector"][..., :8].reshape(*obs.goal_index.shape, 4, 2)
        to_goal = jnp.take_along_axis(offsets, obs.goal_index[..., None, None], axis=-2)[..., 0, :]
        value = 1.0 - 0.1 * jnp.linalg.norm(to_goal, axis=-1)
        pi = DiagGaussian(0.25 * to_goal, jnp.full_like(to_goal, 0.1))
        return PolicyOutput(pi, value, value, value)


def test_gcrl_agent_pursues_the_coordinators_goal_and_turns_from_its_avoid_set():
    """`gcrl.coordinator_agent` under the coordinator on `(!yellow_0 U blue_0) & (!green_1 U
    magenta_1)`: each agent's action is its own reach colour's mean, except where its avoided
    colour's value is above 0.85 and the goal's (the goal's mean minus the danger's)."""
    dots = _DotWorld()
    formula = "(!yellow_0 U blue_0) & (!green_1 U magenta_1)"
    task = TaskEnv(SystemWorld(dots), compile_system_specs([formula], dots))
    _, state = task.reset(jax.random.key(0), dots.default_params)
    agent = gcrl.coordinator_agent(_GoalNet(), {"ap": "vector", "ego": "vector"})
    policy = make_coordinator(agent, dots)
    net = {"policy": None, "gcvf": None}

    @jax.jit
    def act(xy):
        obs = dots._obs(xy)
        carry = policy.init(net, obs, state, jax.random.key(1))
        return policy.apply(net, obs, state, carry, jax.random.key(2))[0][0]

    # zones: blue (2, 0), green (0, 2), magenta (-2, 0), yellow (0, -2)
    cases = [
        # 0 by yellow (0.94 > 0.85 and > blue's 0.77): blue's mean minus yellow's;
        # 1 by magenta, its goal (0.93) above green (0.79): magenta's mean
        ([[0.3, -1.5], [-1.5, 0.5]], [[0.5, 0.5], [-0.125, -0.125]]),
        # 0: yellow closer than blue (0.847 vs 0.840) but under 0.85: blue's mean;
        # 1 by green (0.86, magenta 0.79): magenta's mean minus green's
        ([[0.5, -0.55], [0.0, 0.6]], [[0.375, 0.1375], [-0.5, -0.5]]),
    ]
    for xy, want in cases:
        np.testing.assert_allclose(act(jnp.asarray(xy)), want, atol=1e-6, err_msg=str(xy))
    # the coordinator hands one colour per agent; given several, the first is the goal (green)
    two = AgentSubgoal(jnp.array([False, True, True, False]), jnp.zeros(4, bool),
                       jnp.zeros(5, bool), jnp.zeros(5, bool), jnp.bool_(True))
    obs = {k: v[0] for k, v in dots._obs(jnp.zeros((2, 2))).items() if k != "others"}
    np.testing.assert_allclose(agent(net, obs, two, jax.random.key(0)), [0.0, 0.5])


def test_coordinator_agents_take_mode_actions_unless_sampling_is_asked():
    """The coordinator's DeepLTL and GenZ-LTL agents: the mean action whatever the key (the
    grid's mode actions), a key-dependent draw with `deterministic=False`; GCRL-LTL refuses
    sampling."""
    from types import SimpleNamespace

    from specrl_jax.benchmark import grid, reproduce

    class Net:
        continuous = True

        def apply(self, params, obs):
            mean = jnp.array([0.5, -0.5, 0.0])  # the last output is DeepLTL's epsilon
            zero = jnp.zeros(())
            return PolicyOutput(DiagGaussian(mean, jnp.full(3, 0.3)), zero, zero, zero)

    class GenZNet(Net):
        def apply(self, params, parts):
            out = super().apply(params, parts)
            return out._replace(pi=DiagGaussian(out.pi.mean[:2], out.pi.std[:2]))

    obs = {"ap": jnp.zeros((4, 16)), "ego": jnp.zeros(16)}
    kinds = {"ap": "lidar", "ego": "vector"}
    keys = jax.random.split(jax.random.key(0), 2)
    agents = [  # (builder, network, the subgoal it reads)
        (reproduce._deepltl_agent, Net(),
         SimpleNamespace(reach_symbols=jnp.zeros(5, bool), avoid_symbols=jnp.zeros(5, bool))),
        (reproduce._genz_agent, GenZNet(),
         SimpleNamespace(reach=jnp.zeros(4, bool).at[0].set(True), avoid=jnp.zeros(4, bool))),
    ]
    for builder, network, goal in agents:
        mode = builder(network, kinds)
        sampled = builder(network, kinds, deterministic=False)
        for key in keys:
            np.testing.assert_array_equal(mode(None, obs, goal, key), [0.5, -0.5])
        a, b = (np.asarray(sampled(None, obs, goal, key)) for key in keys)
        assert a.shape == (2,) and not np.allclose(a, b) and not np.allclose(a, [0.5, -0.5])
    with pytest.raises(ValueError, match="GCRL-LTL's coordinator agent acts on"):
        reproduce.evaluate_coordinator(grid.cell("PointLTL0MA2-v0/gcrl+coordinator"), None,
                                       ["multi_agent_zone/infinite/per"], print,
                                       deterministic=False)
