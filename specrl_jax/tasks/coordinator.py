"""The central coordinator for system-level specifications over a multi-agent world.

The paper's protocol: the system-level spec is compiled to one automaton over the joint
propositions `<colour>_<i>`; in each automaton state the shortest candidate reach-avoid sequence
is executed; its current subgoal is a set of joint assignments to reach and one to avoid, split
by agent index into a single-agent subgoal per agent (reach / avoid over the single-agent
colours); a single-agent policy then acts on each agent's own observation, and the automaton is
tracked on the joint label by the ordinary task loop (`TaskEnv` over `SystemWorld`), so
`eval.evaluate` and `eval.suites.evaluate_suites` score the coordinator unchanged.

The split of one pair (`split_subgoal`):
- the reach set's joint assignment of fewest true propositions is chosen (ties: the first in
  alphabet order); agent i's reach is its part of it, and an agent whose part is "no colour" has
  no part in the subgoal and holds still (zero action);
- agent i avoids its label s where some avoided joint assignment gives agent i the label s while
  every other agent is either outside all zones or at its own part (what agent i alone could
  cause while the others are on their way or there); never its own reach.
An epsilon pair (limit-deterministic automata) is taken when the joint label is outside the next
pair's avoid set, as DeepLTL's rule; until then the agents work towards the next pair's reach
under the current avoid set.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata
from specrl_jax.envs.wrappers import Wrapper
from specrl_jax.tasks.policy import StatefulPolicy

#: (agent_params, obs_i, subgoal_i, key) -> action_i: a single-agent policy reading one agent's
#: observation (the single-agent world's dict) and its part of the subgoal (`AgentSubgoal`, one
#: agent's fields)
AgentPolicy = Callable[[Any, dict, "AgentSubgoal", jax.Array], jax.Array]


class AgentSubgoal(NamedTuple):
    """The current subgoal split by agent (leading axis N; one agent's row for an `AgentPolicy`).

    `reach`, `avoid`: bool[N, P] over the single-agent propositions; `reach_symbols`,
    `avoid_symbols`: bool[N, B] the same over the single-agent alphabet (B labels, the empty one
    included, so "leave no zone" can be avoided); `active`: bool[N], the agent has a part.
    """

    reach: jax.Array
    avoid: jax.Array
    reach_symbols: jax.Array
    avoid_symbols: jax.Array
    active: jax.Array


class SystemWorld(Wrapper):
    """A multi-agent world seen by the task loop as one system: `terminated` is `bool[]`, True
    once any agent has terminated (left the arena), and `truncated` `bool[]` at the horizon.
    Everything else (joint labels and alphabet, stacked observation and action) is the world's.

    One agent lost ends the system's episode: a system-level spec over every agent can no longer
    be pursued (docs/fidelity.md, "multi-agent coordinator: termination").
    """

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any = None):
        params = self.env.default_params if params is None else params
        obs, state, reward, terminated, _, info = self.env.step(key, state, action, params)
        any_terminated = jnp.any(terminated)
        truncated = (state.time >= params.max_steps) & ~any_terminated
        return obs, state, jnp.sum(reward), any_terminated, truncated, info


def agent_codes(joint_alphabet: np.ndarray, agent_alphabet: np.ndarray, num_agents: int
                ) -> np.ndarray:
    """int32[A, N]: for each joint assignment, each agent's row of the single-agent alphabet.

    Args:
        joint_alphabet: bool[A, N * P], agent-major (`env.alphabet`).
        agent_alphabet: bool[B, P], one agent's labels (`env.world.alphabet`).
    """
    joint = np.asarray(joint_alphabet, bool)
    agent = np.asarray(agent_alphabet, bool)
    num_props = agent.shape[1]
    if joint.shape[1] != num_agents * num_props:
        raise ValueError(f"joint alphabet over {joint.shape[1]} propositions; expected "
                         f"{num_agents} agents x {num_props}")
    parts = joint.reshape(joint.shape[0], num_agents, 1, num_props)
    match = np.all(parts == agent[None, None], axis=-1)  # [A, N, B]
    if not match.any(-1).all():
        raise ValueError("the joint alphabet has an agent label outside the single-agent alphabet")
    return np.argmax(match, axis=-1).astype(np.int32)


def split_subgoal(reach: jax.Array, avoid: jax.Array, codes: jax.Array, agent_alphabet: jax.Array
                  ) -> AgentSubgoal:
    """One joint reach-avoid pair -> each agent's part (module docstring; jittable).

    Args:
        reach, avoid: bool[A] joint assignments to reach / avoid.
        codes: int32[A, N] (`agent_codes`); agent_alphabet: bool[B, P].

    Returns:
        `AgentSubgoal` (an empty reach makes every agent inactive).
    """
    agent_alphabet = jnp.asarray(agent_alphabet, bool)
    num_labels = agent_alphabet.shape[0]
    empty = jnp.argmin(agent_alphabet.sum(-1))  # the "no colour" label
    weight = agent_alphabet.sum(-1)[codes].sum(-1)  # [A] true propositions of each assignment
    chosen = jnp.argmin(jnp.where(reach, weight, jnp.iinfo(jnp.int32).max))
    target = codes[chosen]  # [N]
    active = (target != empty) & jnp.any(reach)
    # others_ok[a, i]: every agent j != i is outside all zones or at its own part in assignment a
    ok = (codes == empty) | (codes == target[None, :])  # [A, N]
    not_ok = (~ok).sum(-1, keepdims=True) - (~ok)  # [A, N] agents j != i that are not ok
    causes = avoid[:, None] & (not_ok == 0)  # [A, N]
    one_hot = codes[..., None] == jnp.arange(num_labels)  # [A, N, B]
    avoid_symbols = jnp.any(causes[..., None] & one_hot, axis=0)  # [N, B]
    reach_symbols = (jnp.arange(num_labels)[None, :] == target[:, None]) & active[:, None]
    avoid_symbols = avoid_symbols & ~reach_symbols
    to_props = lambda sym: jnp.any(sym[..., None] & agent_alphabet, axis=-2)
    return AgentSubgoal(to_props(reach_symbols), to_props(avoid_symbols), reach_symbols,
                        avoid_symbols, active)


class CoordinatorCarry(NamedTuple):
    stuck: jax.Array  # bool[], no candidate sequence in a live state: the episode is given up


class Subgoal(NamedTuple):
    """The coordinator's decision in one automaton state (one env)."""

    agents: AgentSubgoal
    take_epsilon: jax.Array  # bool[], take the epsilon edge now
    epsilon_slot: jax.Array  # int32[], its slot (-1 if none)
    stuck: jax.Array  # bool[]


def shortest_candidate(spec: Any, q: jax.Array) -> jax.Array:
    """int32[]: the shortest valid candidate sequence of state `q` (ties: the first)."""
    lengths = jnp.where(spec.seq_valid[q], spec.seq_length[q], jnp.iinfo(jnp.int32).max)
    return jnp.argmin(lengths).astype(jnp.int32)


def current_subgoal(spec: Any, q: jax.Array, symbol: jax.Array, codes: jax.Array,
                    agent_alphabet: jax.Array) -> Subgoal:
    """The subgoal of automaton state `q` (shortest candidate, its first pair), split by agent;
    `symbol` int32[] is the current joint label's row of the alphabet (A: none)."""
    c = shortest_candidate(spec, q)
    length = spec.seq_length[q, c]
    seq = automata.pairs(spec, spec.seq_pair[q, c])  # [L]
    second = jnp.minimum(1, length - 1)
    is_eps = seq.epsilon[0]
    take = is_eps & ((second == 0) | ~seq.avoid[second, symbol])
    reach = jnp.where(is_eps, seq.reach[second], seq.reach[0])
    agents = split_subgoal(reach, seq.avoid[0], codes, agent_alphabet)
    live = ~spec.violation[q] & ~(spec.success[q] & spec.is_finite)
    stuck = live & ~jnp.any(spec.seq_valid[q])
    return Subgoal(agents, take, jnp.where(take, seq.epsilon_slot[0], -1), stuck)


def agent_observations(obs: dict[str, jax.Array], keys: Sequence[str]) -> dict[str, jax.Array]:
    """The stacked world observation restricted to `keys` (leading axis N kept): what a
    single-agent policy reads of each agent (e.g. `("ap", "ego")`, without `others`)."""
    missing = set(keys) - set(obs)
    if missing:
        raise ValueError(f"observation keys {sorted(missing)} not in the world's {sorted(obs)}")
    return {k: obs[k] for k in keys}


def check_spec_agents(formula: str, env: Any) -> None:
    """Raise a clear `ValueError` where `formula` names a proposition `<name>_<i>` of an agent
    the world does not have (or an unknown proposition)."""
    import spot

    names = sorted(str(ap) for ap in spot.atomic_prop_collect(spot.formula(formula)))
    unknown = [n for n in names if n not in env.propositions]
    if not unknown:
        return
    agents = []
    for name in unknown:
        head, _, index = name.rpartition("_")
        if index.isdigit() and int(index) >= env.num_agents:
            agents.append(f"{name} (agent {index})")
    if agents:
        raise ValueError(f"spec {formula!r} names agents the world does not have: "
                         f"{', '.join(agents)}; it has {env.num_agents} agents, "
                         f"{', '.join(env.agents)}")
    raise ValueError(f"spec {formula!r} names unknown propositions {unknown}; the world has "
                     f"{', '.join(env.propositions)}")


def compile_system_specs(formulas: Sequence[str], env: Any) -> Any:
    """Check and compile system-level formulas over `env`'s joint propositions; stacked."""
    for formula in formulas:
        check_spec_agents(formula, env)
    return automata.compile_suite(formulas, env.propositions, env.alphabet)


def make_coordinator(agent_policy: AgentPolicy, env: Any, obs_keys: Sequence[str] = ("ap", "ego")
                     ) -> StatefulPolicy:
    """The central coordinator as a `StatefulPolicy` over a multi-agent world (`TaskEnv` over
    `SystemWorld(env)`): its action is the stacked `float32[N, D]` world action.

    Args:
        agent_policy: one single-agent policy run on every agent (`AgentPolicy`); its params are
            the coordinator's `policy_params` (one set shared by all agents).
        env: the multi-agent world (`envs.multi.MultiZoneEnv`, or `SystemWorld` over it).
        obs_keys: the observation parts a single-agent policy reads.

    Agents with no part in the subgoal, and every agent during an epsilon step, get a zero
    action. A live automaton state without candidates gives the episode up (`aborted`).
    """
    for name in ("agents", "num_agents", "world"):
        if not hasattr(env, name):
            raise TypeError(f"make_coordinator needs a multi-agent world (env.{name}); got "
                            f"{type(env).__name__}")
    num_agents = int(env.num_agents)
    agent_alphabet = np.asarray(env.world.alphabet, bool)
    codes = jnp.asarray(agent_codes(np.asarray(env.alphabet), agent_alphabet, num_agents))
    agent_alphabet = jnp.asarray(agent_alphabet)
    joint_alphabet = jnp.asarray(env.alphabet, bool)
    action_shape = tuple(env.action_space.shape)
    keys = tuple(obs_keys)

    def decide(task_state) -> Subgoal:
        symbol = automata.label_symbol(joint_alphabet, task_state.propositions)
        return current_subgoal(task_state.spec, task_state.q, symbol, codes, agent_alphabet)

    def init(params, obs, task_state, key):
        return CoordinatorCarry(decide(task_state).stuck)

    def apply(params, obs, task_state, carry, key):
        goal = decide(task_state)
        per_agent = agent_observations(obs, keys)
        agent_keys = jax.random.split(key, num_agents)
        actions = jax.vmap(agent_policy, in_axes=(None, 0, 0, 0))(
            params, per_agent, goal.agents, agent_keys)
        actions = actions.reshape(action_shape)
        hold = ~goal.agents.active | goal.take_epsilon
        actions = jnp.where(hold[:, None], 0.0, actions).astype(jnp.float32)
        return (actions, goal.epsilon_slot), CoordinatorCarry(goal.stuck)

    return StatefulPolicy(init, apply, aborted=lambda carry: carry.stuck)
