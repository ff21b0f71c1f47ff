"""The task layer: an env joined with a stacked batch of compiled specs.

Per step (reference notes, automata section 3): env step -> label -> automaton step ->
success / violation / accepting visit -> reward -> termination -> auto-reset.

- The reset label is never fed to the automaton; an episode starts in `spec.init`.
- An epsilon step (`take_epsilon` while the automaton state has an epsilon successor) follows
  the epsilon edge, does not step the world (obs and label are kept) and counts toward the
  horizon. Asking for one where none exists steps the world with `action` instead, so methods
  that never use epsilon edges can ignore them.
- Finite-horizon (co-safe) specs end on success or violation; infinite-horizon ones on violation;
  both on the world's own termination, and are truncated at `params.max_steps` task steps.
- Reward (a progress reward in the spirit of the paper's; docs/fidelity.md says how it differs
  from DeepLTL's and GenZ-LTL's): +1 when the automaton makes progress (it
  leaves its state for a non-violating one, or takes an accepting transition: the current
  reach subgoal is achieved), -1 when it enters a violating state (an avoid subgoal is hit),
  0 otherwise, epsilon steps included.
- On reset: a fresh layout and the next spec of the batch (`(spec_index + 1) % K`).
"""

from __future__ import annotations

import hashlib
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax import automata
from specrl_jax.envs.base import Obs
from specrl_jax.envs.wrappers import select_tree


class SpecBank:
    """The stacked specs that task states point into by `spec_index`.

    Held by `TaskState` as static metadata, so that a batch of task states carries one int32
    index per env instead of a copy of its spec's tensors. Banks compare by content (a digest of
    every leaf), so task states of two `TaskEnv`s over equal specs mix and share compilations.
    """

    def __init__(self, specs: Any):
        self.specs = specs
        digest = hashlib.sha256()
        for leaf in jax.tree.leaves(specs):
            leaf = np.asarray(leaf)
            digest.update(f"{leaf.dtype}{leaf.shape}".encode())
            digest.update(leaf.tobytes())
        self.digest = digest.hexdigest()

    def __hash__(self) -> int:
        return hash(self.digest)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SpecBank) and self.digest == other.digest


@struct.dataclass
class TaskState:
    """The state of one task episode."""

    env_state: Any  # the world's state
    obs: Obs  # last observation, returned again by an epsilon step
    propositions: jax.Array  # bool[P], last label (all False at reset)
    spec_index: jax.Array  # int32[], the episode's spec in the stacked batch
    q: jax.Array  # int32[], automaton state
    time: jax.Array  # int32[], task steps so far (world steps + epsilon steps)
    steps_in_q: jax.Array  # int32[], steps since `q` last changed
    num_accepting: jax.Array  # int32[], accepting transitions taken this episode
    success: jax.Array  # bool[], the episode has succeeded (finite-horizon specs)
    violation: jax.Array  # bool[], the episode has violated the spec
    bank: SpecBank = struct.field(pytree_node=False)  # the stacked specs (static)

    @property
    def spec(self) -> Any:
        """The episode's `CompiledSpec`, read from the stacked batch at `spec_index`. Under
        `jit` only the entries a caller uses are gathered; called eagerly on a batch of states,
        it copies every table once per state."""
        return take_spec(self.bank.specs, self.spec_index)


def take_spec(specs: Any, index: jax.Array) -> Any:
    """The spec at `index` of a stacked batch (every leaf indexed on axis 0)."""
    return jax.tree.map(lambda leaf: leaf[index], specs)


def num_specs(specs: Any) -> int:
    """Size `K` of the leading axis of a stacked batch of specs."""
    return int(specs.delta.shape[0])


def reward_progress(q: jax.Array, q_next: jax.Array, accepted: jax.Array,
                    violation: jax.Array, is_epsilon: jax.Array) -> jax.Array:
    """float32[]: +1 on progress (new non-violating state or accepting transition), -1 on
    entering violation, 0 otherwise and on epsilon steps."""
    progress = ((q_next != q) | accepted) & ~violation
    reward = jnp.where(violation, -1.0, jnp.where(progress, 1.0, 0.0))
    return jnp.where(is_epsilon, 0.0, reward).astype(jnp.float32)


class TaskEnv:
    """`env` x a stacked batch of `K` compiled specs, auto-resetting.

    Observation: the world's observation dict. Action: the world's action, plus an optional
    `take_epsilon: bool[]`. State: `TaskState`. `info` holds `propositions`, `success`,
    `violation`, `accepted`, `epsilon` (an epsilon step was taken), `num_accepting_visits`,
    `steps`, `spec_index` (all of the step taken, before any reset) and `final_observation`.
    """

    def __init__(self, env: Any, specs: Any):
        if not hasattr(specs, "delta") or jnp.ndim(specs.delta) != 3:
            raise ValueError(
                "specs must be a stacked batch of CompiledSpec (delta of shape [K, S, A]); "
                "use specrl_jax.automata.stack([...])"
            )
        num_symbols = int(specs.delta.shape[2])
        if int(env.alphabet.shape[0]) != num_symbols:
            raise ValueError(
                f"specs are compiled over {num_symbols} alphabet symbols but {env!r} has "
                f"{int(env.alphabet.shape[0])}; compile them with alphabet=env.alphabet"
            )
        self.env = env
        self.specs = specs
        self.num_specs = num_specs(specs)
        self._bank = SpecBank(specs)
        # the env's symbol is a row of its own alphabet: usable only where the specs' rows are
        # the same assignments in the same order (else the step looks the label up)
        self._symbol_is_spec_row = bool(
            np.array_equal(np.asarray(specs.alphabet[0]), np.asarray(env.alphabet)))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def reset(self, key: jax.Array, params: Any = None, spec_index: jax.Array | None = None
              ) -> tuple[Obs, TaskState]:
        """Fresh layout; the spec at `spec_index`, or a uniformly drawn one when None."""
        params = self.env.default_params if params is None else params
        key_env, key_spec = jax.random.split(key)
        if spec_index is None:
            spec_index = jax.random.randint(key_spec, (), 0, self.num_specs)
        obs, env_state = self.env.reset(key_env, params)
        spec_index = jnp.asarray(spec_index, jnp.int32)
        zero = jnp.zeros((), jnp.int32)
        state = TaskState(
            env_state=env_state,
            obs=obs,
            propositions=jnp.zeros((self.env.num_propositions,), bool),
            spec_index=spec_index,
            q=self.specs.init[spec_index].astype(jnp.int32),
            time=zero,
            steps_in_q=zero,
            num_accepting=zero,
            success=jnp.zeros((), bool),
            violation=jnp.zeros((), bool),
            bank=self._bank,
        )
        return obs, state

    def step_task(self, key: jax.Array, state: TaskState, action: jax.Array, params: Any = None,
                  take_epsilon: jax.Array | bool = False):
        """One task step without auto-reset: `(obs, state, reward, terminated, truncated, info)`."""
        params = self.env.default_params if params is None else params
        slot = automata.epsilon_slot(take_epsilon)
        is_epsilon = automata.takes_epsilon(state.spec, state.q, slot)
        obs_env, env_state, _, env_terminated, _, env_info = self.env.step(
            key, state.env_state, action, params
        )
        obs = select_tree(is_epsilon, state.obs, obs_env)
        env_state = select_tree(is_epsilon, state.env_state, env_state)
        propositions = jnp.where(is_epsilon, state.propositions, env_info["propositions"])
        env_terminated = ~is_epsilon & env_terminated

        q_next, accepted, success, violation = automata.step_in_batch(
            self.specs, state.spec_index, state.q, propositions, jnp.where(is_epsilon, slot, -1),
            env_info.get("symbol") if self._symbol_is_spec_row else None,
        )
        success = success & self.specs.is_finite[state.spec_index]
        reward = reward_progress(state.q, q_next, accepted, violation, is_epsilon)
        time = state.time + 1
        terminated = env_terminated | violation | success
        truncated = (time >= params.max_steps) & ~terminated
        new_state = state.replace(
            env_state=env_state,
            obs=obs,
            propositions=propositions,
            q=q_next,
            time=time,
            steps_in_q=jnp.where(q_next == state.q, state.steps_in_q + 1, 0),
            num_accepting=state.num_accepting + accepted.astype(jnp.int32),
            success=state.success | success,
            violation=state.violation | violation,
        )
        info = {
            "propositions": propositions,
            "success": success,
            "violation": violation,
            "accepted": accepted,
            "epsilon": is_epsilon,
            "num_accepting_visits": new_state.num_accepting,
            "steps": time,
            "spec_index": state.spec_index,
        }
        return obs, new_state, reward, terminated, truncated, info

    def step(self, key: jax.Array, state: TaskState, action: jax.Array, params: Any = None,
             take_epsilon: jax.Array | bool = False):
        """One task step; an ended episode restarts on a fresh layout with the next spec."""
        params = self.env.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, new_state, reward, terminated, truncated, info = self.step_task(
            key_step, state, action, params, take_epsilon
        )
        done = terminated | truncated
        next_index = (state.spec_index + 1) % self.num_specs
        obs_reset, state_reset = self.reset(key_reset, params, next_index)
        info["final_observation"] = obs
        obs = select_tree(done, obs_reset, obs)
        new_state = select_tree(done, state_reset, new_state)
        return obs, new_state, reward, terminated, truncated, info
