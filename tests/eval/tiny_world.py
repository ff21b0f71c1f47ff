"""A tiny LetterWorld-like torus and hand-built automata, for task and evaluation tests.

The world: an N x N torus, one cell per letter of `letters` (never (0, 0)), the agent starting
at (0, 0), actions up/down/left/right, the label = the letter under the agent. Specs are
hand-written automata over the alphabet "nothing, a, b, c" (rows 0..3).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.automata.tensors import pack_step_planes, pack_step_table, symbol_of_code
from specrl_jax.envs.base import Env
from specrl_jax.envs.spaces import Box, Dict, Discrete

MOVES = np.array([(-1, 0), (1, 0), (0, -1), (0, 1)])


@dataclass(frozen=True)
class TinyConfig:
    grid_size: int = 5
    num_letters: int = 3


@struct.dataclass
class TinyParams:
    max_steps: int = 20


@struct.dataclass
class TinyState:
    letters: jax.Array  # int8[N, N], -1 empty
    agent: jax.Array  # int32[2]
    time: jax.Array  # int32[]


class TinyWorld(Env):
    def __init__(self, config: TinyConfig = TinyConfig()):
        self.config = config
        self.propositions = tuple("abcdefgh"[: config.num_letters])

    @property
    def default_params(self) -> TinyParams:
        return TinyParams()

    @property
    def action_space(self) -> Discrete:
        return Discrete(4)

    @property
    def observation_space(self) -> Dict:
        n, p = self.config.grid_size, self.config.num_letters
        return Dict({"ap": Box(0, 1, (n, n, p), jnp.uint8), "ego": Box(0, 1, (n, n, 1), jnp.uint8)})

    @property
    def alphabet(self) -> jax.Array:
        p = self.config.num_letters
        return jnp.concatenate([jnp.zeros((1, p), bool), jnp.eye(p, dtype=bool)])

    def _obs(self, state: TinyState) -> dict:
        n, p = self.config.grid_size, self.config.num_letters
        ap = (state.letters[..., None] == jnp.arange(p, dtype=jnp.int8)).astype(jnp.uint8)
        ego = jnp.zeros((n, n, 1), jnp.uint8).at[state.agent[0], state.agent[1], 0].set(1)
        return {"ap": ap, "ego": ego}

    def _label(self, state: TinyState) -> jax.Array:
        letter = state.letters[state.agent[0], state.agent[1]]
        return letter == jnp.arange(self.config.num_letters, dtype=jnp.int8)

    def reset_env(self, key, params):
        n, p = self.config.grid_size, self.config.num_letters
        cells = 1 + jax.random.permutation(key, n * n - 1)[:p]
        letters = jnp.full((n * n,), -1, jnp.int8).at[cells].set(jnp.arange(p, dtype=jnp.int8))
        return self.reset_to(key, {"letters": letters.reshape(n, n)}, params)

    def reset_to(self, key, layout, params):
        state = TinyState(jnp.asarray(layout["letters"], jnp.int8), jnp.zeros(2, jnp.int32),
                          jnp.zeros((), jnp.int32))
        return self._obs(state), state

    def step_env(self, key, state, action, params):
        agent = (state.agent + jnp.asarray(MOVES)[action]) % self.config.grid_size
        state = state.replace(agent=agent.astype(jnp.int32), time=state.time + 1)
        info = {"propositions": self._label(state)}
        return self._obs(state), state, jnp.zeros(()), jnp.zeros((), bool), info

    def layout(self, state):
        return {"letters": state.letters, "agent": state.agent}


@struct.dataclass
class HandSpec:
    """The CompiledSpec fields the task layer and the planner read."""

    delta: jax.Array
    accepting: jax.Array
    epsilon: jax.Array
    success: jax.Array
    violation: jax.Array
    init: jax.Array
    is_finite: jax.Array
    alphabet: jax.Array
    step_table: jax.Array
    symbol_of_code: jax.Array
    step_planes: jax.Array


NUM_STATES = 4
ALPHABET = np.concatenate([np.zeros((1, 3), bool), np.eye(3, dtype=bool)])


def hand_spec(delta, accepting_into=(), accepting_edges=(), epsilon=None, success=(),
              violation=(), finite=True) -> HandSpec:
    """An automaton over symbols (none, a, b, c), padded to 4 states with self-loops."""
    delta = np.asarray(delta, np.int32)
    s = delta.shape[0]
    full = np.tile(np.arange(NUM_STATES, dtype=np.int32)[:, None], (1, 4))
    full[:s] = delta
    accepting = np.isin(full, list(accepting_into))
    accepting[s:] = False
    for q, a in accepting_edges:
        accepting[q, a] = True
    eps = np.full((NUM_STATES, 1), -1, np.int32)
    for q, target in (epsilon or {}).items():
        eps[q, 0] = target
    mask = lambda idx: np.isin(np.arange(NUM_STATES), list(idx))
    arrays = {"delta": full, "accepting": accepting, "epsilon": eps,
              "success": mask(success), "violation": mask(violation)}
    table = pack_step_table(arrays)
    return HandSpec(**{k: jnp.asarray(v) for k, v in arrays.items()},
                    init=jnp.asarray(0, jnp.int32), is_finite=jnp.asarray(finite),
                    alphabet=jnp.asarray(ALPHABET), step_table=jnp.asarray(table),
                    symbol_of_code=jnp.asarray(symbol_of_code(ALPHABET)),
                    step_planes=jnp.asarray(pack_step_planes(table)))


def reach_avoid_spec() -> HandSpec:
    """`!c U (a & F b)`: 0 -a-> 1 -b-> 2 (success); c in state 0 -> 3 (violation)."""
    return hand_spec([[0, 1, 0, 3], [1, 1, 2, 1], [2, 2, 2, 2], [3, 3, 3, 3]],
                     accepting_into=(2,), success=(2,), violation=(3,))


def recurrence_spec() -> HandSpec:
    """`GF a & GF b & G !c`: 0 -a-> 1 -b-> 0 (accepting); c -> 2 (violation)."""
    return hand_spec([[0, 1, 0, 2], [1, 1, 0, 2], [2, 2, 2, 2]],
                     accepting_edges=((1, 2),), violation=(2,), finite=False)


def persistence_spec() -> HandSpec:
    """`FG a`-like: state 0 waits, epsilon -> 1, where every a is accepting and else 2 (violation)."""
    return hand_spec([[0, 0, 0, 0], [2, 1, 2, 2], [2, 2, 2, 2]],
                     accepting_edges=((1, 1),), epsilon={0: 1}, violation=(2,), finite=False)


def stack_specs(specs: list[HandSpec]) -> HandSpec:
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *specs)
