"""What the evaluator accepts as a policy, and the uniformly random floor.

A policy is either a pure function

    policy(policy_params, obs, task_state, key) -> action  or  (action, take_epsilon)

or a `StatefulPolicy` whose carry lives for one episode (a chosen subgoal, a replanning timer):

    carry = init(policy_params, obs, task_state, key)              # at every episode start
    action_or_pair, carry = apply(policy_params, obs, task_state, carry, key)
    gave_up = aborted(carry)                                       # optional, bool[]

A policy that can find no way forward (GenZ-LTL's `NoPathsException`) gives up through
`aborted`, read on the carry `apply` returns: the episode ends there, before that step is taken,
and counts as neither success nor violation (nor in `mu_acc`).

`task_state` is a `specrl_jax.tasks.TaskState`: the automaton state `q`, the episode's spec
`spec` (read from the stacked batch at `spec_index`, not stored per env), the step count `time`,
`steps_in_q` and the world's state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from specrl_jax.automata import epsilon_slot


class StatefulPolicy(NamedTuple):
    """A policy with per-episode memory (see the module docstring for the signatures);
    `aborted` (optional) says from the carry that the policy gave the episode up."""

    init: Callable[..., Any]
    apply: Callable[..., tuple[Any, Any]]
    aborted: Callable[[Any], jax.Array] | None = None


def as_stateful(policy: Callable[..., Any] | StatefulPolicy) -> StatefulPolicy:
    """Wrap a pure policy function as a `StatefulPolicy` with an empty carry."""
    if isinstance(policy, StatefulPolicy):
        return policy
    if not callable(policy):
        raise TypeError(
            f"policy must be a callable (params, obs, task_state, key) -> action or a "
            f"StatefulPolicy, got {type(policy).__name__}"
        )

    def init(policy_params: Any, obs: Any, task_state: Any, key: jax.Array) -> tuple[()]:
        return ()

    def apply(policy_params: Any, obs: Any, task_state: Any, carry: Any, key: jax.Array):
        return policy(policy_params, obs, task_state, key), carry

    return StatefulPolicy(init, apply)


def split_action(output: Any) -> tuple[jax.Array, jax.Array]:
    """`action` or `(action, take_epsilon)` -> `(action, epsilon slot int32[])`: a bool
    `take_epsilon` means slot 0 or none, an integer is the slot itself (negative: none), as in
    `automata.step`."""
    if isinstance(output, tuple):
        if len(output) != 2:
            raise TypeError(
                f"a policy returns an action or a pair (action, take_epsilon); got a tuple of "
                f"{len(output)} elements"
            )
        action, take_epsilon = output
        return action, epsilon_slot(take_epsilon)
    return output, jnp.full((), -1, jnp.int32)


def random_policy(env: Any) -> Callable[..., jax.Array]:
    """Uniformly random actions from `env.action_space`, never an epsilon step (any env)."""
    space = env.action_space

    def policy(policy_params: Any, obs: Any, task_state: Any, key: jax.Array) -> jax.Array:
        return space.sample(key)

    return policy
