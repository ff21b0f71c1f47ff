"""A user's own tiny network, trained in about 20 s on a CPU, scored on the benchmark.

The network (a flax MLP, 4,356 parameters) sees what a user would hand it: the LetterWorld view
reduced by the automaton's current subgoal, two V x V channels (cells holding a letter to reach,
cells holding a letter to avoid, for the first valid one-step subgoal `spec.subgoal_reach[q, g]`
/ `spec.subgoal_avoid[q, g]`), and returns 4 action logits. It learns by behaviour cloning: the
hand-written agent of `letter_subgoal_agent.py` is rolled through the task loop (`tasks.TaskEnv`,
auto-resetting, under `jit`) on random two-step reach-avoid formulas of the user's own (none of
the paper suites it is scored on), and the MLP is fitted to its actions with optax. Neither one
of the five baselines nor the project's PPO trainer takes part.

What it shows: a trained network's weights travel in `Agent.params`; the policy is a pure
function of `(params, obs, task_state, key)`; the factory trains (deterministically for a seed)
once per world.

    python examples/letter_tiny_network.py                        # train, 1 seed x 20 episodes
    specrl-jax eval --env LetterLTL0-v0 --suite letter/finite/ind \\
        --policy letter_tiny_network:make_agent                   # with examples/ on PYTHONPATH
    specrl-jax bench --worlds letter --policy letter_tiny_network:make_agent
"""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from letter_subgoal_agent import make_agent as make_teacher

from specrl_jax import automata
from specrl_jax.benchmark.agent import Agent
from specrl_jax.tasks import TaskEnv

NUM_ENVS, NUM_STEPS = 1024, 64  # the teacher's rollouts: 65,536 states
STEPS = 4000  # optimiser steps of 256 states


class TinyNetwork(nn.Module):
    """An MLP: float32[..., 2 V V] subgoal view -> float32[..., 4] action logits."""

    hidden: int = 32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.relu(nn.Dense(self.hidden)(x))
        x = nn.relu(nn.Dense(self.hidden)(x))
        return nn.Dense(4)(x)


def subgoal_view(alphabet: jax.Array, obs: dict, task_state: Any) -> jax.Array:
    """float32[2 V V]: the cells holding a letter to reach, then those holding one to avoid, for
    the first valid subgoal of the automaton state (as `letter_subgoal_agent` reads them)."""
    spec, q = task_state.spec, task_state.q
    g = jnp.argmax(spec.subgoal_valid[q])
    reach = (spec.subgoal_reach[q, g][:, None] & alphabet).any(0)  # bool[P]
    avoid = (spec.subgoal_avoid[q, g][:, None] & alphabet).any(0)  # bool[P]
    ap = obs["ap"].astype(bool)  # bool[V, V, P]
    channels = jnp.stack([(ap & reach).any(-1), (ap & avoid).any(-1)])  # bool[2, V, V]
    return channels.reshape(-1).astype(jnp.float32)


def training_formulas(letters: tuple[str, ...], num: int = 32, seed: int = 0) -> list[str]:
    """Two-step reach-avoid formulas over random letter sets, as wide as the paper suites'
    subgoals (1-5 letters to reach, 0-6 to avoid): `!(f | g) U ((a | b) & (!(c) U (d)))`."""
    rng = np.random.default_rng(seed)

    def draw(exclude: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        reach = rng.permutation(np.setdiff1d(letters, exclude))[:rng.integers(1, 6)]
        avoid = rng.permutation(np.setdiff1d(letters, reach))[:rng.integers(0, 7)]
        return reach, avoid

    def reach_avoid(reach: np.ndarray, avoid: np.ndarray, then: str | None = None) -> str:
        target = f"({' | '.join(reach)})"
        body = target if then is None else f"({target} & ({then}))"
        return f"!({' | '.join(avoid)}) U {body}" if len(avoid) else f"F {body}"

    formulas = []
    for _ in range(num):
        last = draw(np.array([], str))
        first = draw(last[1])  # the last step's letters to avoid may not be the first's to reach
        formulas.append(reach_avoid(*first, reach_avoid(*last)))
    return formulas


def teacher_states(world: Any, key: jax.Array, num_envs: int = NUM_ENVS,
                   num_steps: int = NUM_STEPS) -> tuple[jax.Array, jax.Array]:
    """The teacher's inputs and actions on the states of its own rollouts.

    Returns:
        `(views float32[N, 2 V V], actions int32[N])`, N = num_envs * num_steps.
    """
    return _rollout(world, num_envs, num_steps)(key)


@functools.cache  # one compiled rollout per world and size
def _rollout(world: Any, num_envs: int, num_steps: int) -> Callable[[jax.Array], Any]:
    alphabet = jnp.asarray(world.alphabet)
    teacher = make_teacher(world).policy
    formulas = training_formulas(tuple(world.propositions))
    task = TaskEnv(world, automata.compile_suite(formulas, world.propositions, world.alphabet))

    def step(carry, key):
        obs, state = carry
        key_act, key_env = jax.random.split(key)
        action = jax.vmap(teacher, (None, 0, 0, 0))(None, obs, state,
                                                    jax.random.split(key_act, num_envs))
        view = jax.vmap(subgoal_view, (None, 0, 0))(alphabet, obs, state)
        obs, state, *_ = jax.vmap(task.step)(jax.random.split(key_env, num_envs), state, action)
        return (obs, state), (view, action)

    @jax.jit
    def rollout(key):
        key_reset, key_steps = jax.random.split(key)
        first = jax.vmap(task.reset)(jax.random.split(key_reset, num_envs))
        _, (views, actions) = jax.lax.scan(step, first, jax.random.split(key_steps, num_steps))
        return views.reshape(num_envs * num_steps, -1), actions.reshape(-1)

    return rollout


@functools.partial(jax.jit, static_argnames=("steps", "batch_size", "learning_rate"))
def fit(views: jax.Array, actions: jax.Array, key: jax.Array, steps: int = STEPS,
        batch_size: int = 256, learning_rate: float = 3e-3) -> Any:
    """The network's params fitted to `actions` (cross-entropy, Adam, random minibatches)."""
    network = TinyNetwork()
    optimiser = optax.adam(learning_rate)
    key_init, key_batches = jax.random.split(key)

    def loss(params, batch_views, batch_actions):
        logits = network.apply(params, batch_views)
        return optax.softmax_cross_entropy_with_integer_labels(logits, batch_actions).mean()

    def update(carry, key_batch):
        params, opt_state = carry
        rows = jax.random.randint(key_batch, (batch_size,), 0, views.shape[0])
        grads = jax.grad(loss)(params, views[rows], actions[rows])
        updates, opt_state = optimiser.update(grads, opt_state)
        return (optax.apply_updates(params, updates), opt_state), None

    params = network.init(key_init, views[:1])
    carry = (params, optimiser.init(params))
    (params, _), _ = jax.lax.scan(update, carry, jax.random.split(key_batches, steps))
    return params


def agreement(params: Any, views: jax.Array, actions: jax.Array) -> float:
    """The fraction of states on which the network's most likely action is the teacher's."""
    return float((TinyNetwork().apply(params, views).argmax(-1) == actions).mean())


def train(world: Any, seed: int = 0, steps: int = STEPS, num_envs: int = NUM_ENVS,
          num_steps: int = NUM_STEPS) -> tuple[Any, jax.Array, jax.Array]:
    """Roll the teacher, clone it: `(params, views, actions)`, the same for the same seed."""
    key_data, key_fit = jax.random.split(jax.random.key(seed))
    views, actions = teacher_states(world, key_data, num_envs, num_steps)
    return fit(views, actions, key_fit, steps), views, actions


def network_agent(world: Any, params: Any) -> Agent:
    """The benchmark's view of the network: its policy, with `params` as the agent's params."""
    alphabet = jnp.asarray(world.alphabet)  # bool[A, P]: the letters of each alphabet symbol
    network = TinyNetwork()

    def policy(params: Any, obs: dict, task_state: Any, key: jax.Array) -> jax.Array:
        logits = network.apply(params, subgoal_view(alphabet, obs, task_state))
        return jax.random.categorical(key, logits).astype(jnp.int32)

    return Agent(policy, params=params, name="tiny-network", worlds=("letter",))


def make_agent(world: Any, seed: int = 0, steps: int = STEPS, num_envs: int = NUM_ENVS,
               num_steps: int = NUM_STEPS) -> Agent:
    """The factory `--policy letter_tiny_network:make_agent` names: trains once per world."""
    return network_agent(world, train(world, seed, steps, num_envs, num_steps)[0])


def main() -> int:
    from specrl_jax.benchmark import bench
    from specrl_jax.envs.registry import make

    world, _ = make("LetterLTL0-v0")
    start = time.perf_counter()
    params, views, actions = train(world)
    print(f"trained in {time.perf_counter() - start:.1f} s on {views.shape[0]} teacher states: "
          f"{sum(x.size for x in jax.tree.leaves(params))} parameters, "
          f"{agreement(params, views, actions):.1%} agreement with the teacher")
    report = bench.score(network_agent(world, params), worlds=("letter",), seeds=1, episodes=20,
                         out="bench_letter_tiny_network")  # prints one summary line per world
    print(f"wrote {report.out}/: results.json, metrics.csv, tables.md, bench.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
