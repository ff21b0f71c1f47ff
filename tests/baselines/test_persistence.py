"""Persistence (`F G a & G !(b | c)`) through the test-time agents of GenZ-LTL and DeepLTL, with
scripted networks, on a tiny torus with a stay action: the agent walks to 'a', the planner takes
the epsilon jump there and keeps the subgoal, and the agent stays; no violation, no abort, and
every step after the jump is an accepting visit, so the visits grow one for one with the horizon.
"""

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.baselines import deepltl, genz
from specrl_jax.baselines.ppo.networks import Categorical, PolicyOutput
from specrl_jax.envs.spaces import Discrete
from specrl_jax.eval import evaluate
from tests.eval.tiny_world import MOVES, TinyConfig, TinyParams, TinyWorld

PERSISTENCE = "F G a & G !(b | c)"
STAY = 4
STEPS = np.concatenate([MOVES, [(0, 0)]])


class StayWorld(TinyWorld):
    """The tiny torus with a fifth action that stays in place."""

    obs_kinds = {"ap": "grid", "ego": "grid"}

    @property
    def action_space(self) -> Discrete:
        return Discrete(5)

    def step_env(self, key, state, action, params):
        agent = (state.agent + jnp.asarray(STEPS)[action]) % self.config.grid_size
        state = state.replace(agent=agent.astype(jnp.int32), time=state.time + 1)
        return self._obs(state), state, jnp.zeros(()), jnp.zeros((), bool), {
            "propositions": self._label(state)}


def _move_toward(target: jax.Array, agent: jax.Array, n: int) -> jax.Array:
    """Action (0 up, 1 down, 2 left, 3 right, 4 stay) of one step toward flat cell `target` on
    an n x n torus; stay where the agent is on it."""
    wrap = lambda d: (d + n // 2) % n - n // 2
    di, dj = wrap(target // n - agent // n), wrap(target % n - agent % n)
    return jnp.where(di < 0, 0, jnp.where(di > 0, 1, jnp.where(dj < 0, 2, jnp.where(dj > 0, 3, STAY))))


class GenZScript:
    """A GenZ-LTL network stand-in on the reduced image: toward the reach cell (1.0); where none
    shows (the agent, drawn last, stands on it) stay. Values 1, no cost."""

    def apply(self, params, parts):
        flat = parts["grid"][..., 0].reshape(*parts["grid"].shape[:-3], -1)
        n = parts["grid"].shape[-2]
        agent = jnp.argmax(flat == genz.AGENT, axis=-1)
        shown = jnp.any(flat == genz.REACH, axis=-1)
        target = jnp.where(shown, jnp.argmax(flat == genz.REACH, axis=-1), agent)
        move = _move_toward(target, agent, n)
        ones = jnp.ones(move.shape)
        return PolicyOutput(Categorical(10.0 * jax.nn.one_hot(move, 5)), ones, 0 * ones, 0 * ones)


class DeepLTLScript:
    """A DeepLTL network stand-in: the epsilon action where it is allowed, else toward a
    proposition of the first non-epsilon pair's reach set, staying on it. Values 1."""

    continuous = False
    num_actions = 5

    def __init__(self, alphabet):
        self.alphabet = jnp.asarray(alphabet, bool)

    def apply(self, params, obs):
        return jax.vmap(self._one)(obs) if obs.start.ndim else self._one(obs)

    def _one(self, obs):
        grid = obs.parts["grid"]  # [N, N, P + 1]: the propositions, then the agent
        n = grid.shape[0]
        pair = obs.start + obs.epsilon[obs.start].astype(jnp.int32)
        props = jnp.any(obs.reach[pair][:, None] & self.alphabet, axis=0)  # [P]
        cells = jnp.any((grid[..., :-1] > 0) & props, axis=-1).reshape(-1)
        agent = jnp.argmax(grid[..., -1].reshape(-1))
        target = jnp.where(cells[agent], agent, jnp.argmax(cells))
        move = jnp.where(obs.epsilon_allowed, 5, _move_toward(target, agent, n))
        logits = jnp.where(jnp.arange(6) == move, 10.0, 0.0)
        return PolicyOutput(Categorical(logits), jnp.ones(()), jnp.zeros(()), jnp.zeros(()))


def _outcomes(policy, horizon: int):
    world = StayWorld(TinyConfig(grid_size=5, num_letters=3))
    params = TinyParams(max_steps=horizon)
    return evaluate(policy, (world, params), [PERSISTENCE], seeds=[0], episodes_per_seed=6,
                    horizon=horizon).table


def _check_stays(policy):
    short, long = _outcomes(policy, 20), _outcomes(policy, 45)
    for table in (short, long):
        assert not np.asarray(table.violation).any()
        assert not np.asarray(table.aborted).any()
    visits_short, visits_long = np.asarray(short.num_accepting), np.asarray(long.num_accepting)
    # a 5 x 5 torus: 'a' is at most 4 moves away, then one epsilon step, then a visit per step
    assert (visits_short >= 20 - 4 - 1).all(), visits_short
    np.testing.assert_array_equal(visits_long - visits_short, 25)


def test_genz_agent_jumps_in_the_goal_and_keeps_the_subgoal():
    world = StayWorld(TinyConfig(grid_size=5, num_letters=3))
    # a 6-step subgoal timer: without the jump the automaton never moves, so the reach
    # proposition is given up at the first timeout and, with no candidate left, the episode
    policy = genz.make_policy(GenZScript(), world.alphabet, world.obs_kinds, replan_steps=6)
    _check_stays(policy)
    never = genz.make_policy(GenZScript(), world.alphabet, world.obs_kinds, replan_steps=6,
                             take_epsilon=False)
    table = _outcomes(never, 20)
    assert np.asarray(table.aborted).all() and not np.asarray(table.num_accepting).any()


def test_deepltl_agent_jumps_in_the_goal_and_keeps_its_sequence():
    world = StayWorld(TinyConfig(grid_size=5, num_letters=3))
    policy = deepltl.make_policy(DeepLTLScript(world.alphabet), world.alphabet, world.obs_kinds,
                                 deterministic=True)
    _check_stays(policy)


class DriftWorld(StayWorld):
    """StayWorld whose agent slides onto an empty neighbour cell every `DRIFT` steps whatever
    the action, as the Point robot's momentum carries it out of a zone."""

    def step_env(self, key, state, action, params):
        n = self.config.grid_size
        targets = (state.agent + jnp.asarray(MOVES)) % n  # [4, 2]
        empty = state.letters[targets[:, 0], targets[:, 1]] < 0
        slide = (state.time % DRIFT == DRIFT - 1) & jnp.any(empty)
        action = jnp.where(slide, jnp.argmax(empty), action)
        return super().step_env(key, state, action, params)


DRIFT = 6


def test_leaving_the_goal_after_the_jump_falls_back_and_the_agent_jumps_again():
    world = DriftWorld(TinyConfig(grid_size=5, num_letters=3))
    policy = genz.make_policy(GenZScript(), world.alphabet, world.obs_kinds, replan_steps=6)
    visits_short, visits_long = _clean_visits(world, policy, 30, 60)
    # each drift costs a step back into 'a' and a jump: DRIFT - 2 of every DRIFT steps accept
    assert (visits_long - visits_short >= 30 * (DRIFT - 3) // DRIFT).all(), (visits_short, visits_long)


def _outcomes_in(world, policy, horizon: int):
    params = TinyParams(max_steps=horizon)
    return evaluate(policy, (world, params), [PERSISTENCE], seeds=[0], episodes_per_seed=6,
                    horizon=horizon).table


def _clean_visits(world, policy, *horizons: int) -> list[np.ndarray]:
    """Accepting visits per episode at each horizon, after checking that no episode violated
    or was given up."""
    visits = []
    for horizon in horizons:
        table = _outcomes_in(world, policy, horizon)
        assert not np.asarray(table.violation).any()
        assert not np.asarray(table.aborted).any()
        visits.append(np.asarray(table.num_accepting))
    return visits


class StallWorld(StayWorld):
    """StayWorld whose agent stays put for the first `STALL` steps whatever the action, as the
    Point robot's deterministic policy dithers in place for a while before it sets off."""

    def step_env(self, key, state, action, params):
        return super().step_env(key, state, jnp.where(state.time < STALL, STAY, action), params)


STALL = 10


def test_genz_agent_keeps_the_epsilon_subgoal_through_a_timeout():
    # the subgoal timer (6 steps) fires before the agent can move; the reference marks 'a' on
    # the transitions leaving the initial state only, and the epsilon edge to the loop that
    # reaches 'a' stays open: the agent keeps its subgoal, arrives and stays
    world = StallWorld(TinyConfig(grid_size=5, num_letters=3))
    policy = genz.make_policy(GenZScript(), world.alphabet, world.obs_kinds, replan_steps=6)
    visits_short, visits_long = _clean_visits(world, policy, 30, 55)
    # 'a' is at most 4 moves away once the stall ends, then one epsilon step
    assert (visits_short >= 30 - STALL - 4 - 1).all(), visits_short
    np.testing.assert_array_equal(visits_long - visits_short, 25)
    # an agent that never jumps cannot follow the epsilon edge: its first timeout gives 'a' up
    never = genz.make_policy(GenZScript(), world.alphabet, world.obs_kinds, replan_steps=6,
                             take_epsilon=False)
    table = _outcomes_in(world, never, 30)
    assert np.asarray(table.aborted).all() and (np.asarray(table.steps) == 6).all()


class HesitantScript(DeepLTLScript):
    """DeepLTLScript whose epsilon action, where allowed, has probability 0.4 (staying 0.6):
    below the mode's 0.7, as the trained Point policy in its goal zone."""

    def _one(self, obs):
        out = super()._one(obs)
        logits = jnp.where(obs.epsilon_allowed,
                           jnp.where(jnp.arange(6) == 5, 20.0 + np.log(0.4 / 0.6),
                                     jnp.where(jnp.arange(6) == STAY, 20.0, 0.0)),
                           20.0 * out.pi.logits / 10.0)
        return out._replace(pi=Categorical(logits))


def test_deepltl_samples_its_actions_on_infinite_specs_on_every_world():
    # the original hard-codes sampled actions for infinite tasks (eval_test_tasks_infinite.py),
    # Zone included, where finite tasks take the mode: the mode never jumps at p = 0.4
    from types import SimpleNamespace

    from specrl_jax.benchmark import experiment

    world = StayWorld(TinyConfig(grid_size=5, num_letters=3))
    method = SimpleNamespace(network=HesitantScript(world.alphabet))
    reference = experiment.make_policy("deepltl", world, method, world_family="zone")
    table = _outcomes(reference, 45)
    assert not np.asarray(table.violation).any()
    assert (np.asarray(table.num_accepting) > 0).all(), table.num_accepting
    mode = experiment.make_policy("deepltl", world, method, deterministic=True, world_family="zone")
    assert not np.asarray(_outcomes(mode, 45).num_accepting).any()
