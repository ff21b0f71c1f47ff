"""Mass evaluation: every (seed, spec, episode) of a run in one compiled, `vmap`ped call.

Episode `(seed s, spec k, episode e)` draws all its randomness (layout, policy, world) from
`fold_in(key(s), e)`: every spec meets the same sequence of layouts under a seed, as in the
original protocol (one seeded env reset per episode, the same for every formula), and an
outcome does not depend on which other seeds, specs or episodes run beside it. Results are
deterministic given the seeds. Each episode runs for
exactly the horizon under a `lax.scan` and freezes once it ends (success, violation, the
world's termination, the horizon, or the policy giving it up).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from specrl_jax import automata
from specrl_jax.envs.wrappers import select_tree
from specrl_jax.eval import original_ldba
from specrl_jax.eval.metrics import EpisodeTable, per_seed_metrics, summarize
from specrl_jax.tasks import TaskEnv, TaskState
from specrl_jax.tasks.policy import StatefulPolicy, as_stateful, split_action


@dataclasses.dataclass(frozen=True)
class EvalResult:
    """Outcome of `evaluate`: the episode table plus what is needed to read it."""

    env_id: str
    spec_names: tuple[str, ...]  # formula text (or a given name) per spec
    is_finite: np.ndarray  # bool[num_specs]
    seeds: tuple[int, ...]
    episodes_per_seed: int
    horizon: int
    table: EpisodeTable  # fields [num_seeds, num_specs, episodes_per_seed]

    def per_seed(self) -> dict[str, np.ndarray]:
        """`{metric: float64[num_seeds, num_specs]}`."""
        return per_seed_metrics(self.table)

    def select(self, indices: Sequence[int]) -> EvalResult:
        """The same result restricted to the specs at `indices` (e.g. one suite of a run)."""
        indices = list(indices)
        return dataclasses.replace(
            self,
            spec_names=tuple(self.spec_names[i] for i in indices),
            is_finite=self.is_finite[indices],
            table=EpisodeTable(*(None if x is None else x[:, indices] for x in self.table)),
        )

    def summary(self, spec_groups: dict[str, list[int]] | None = None) -> dict[str, Any]:
        """Mean and std over seeds per spec and per group of spec indices (a suite)."""
        return summarize(self.per_seed(), spec_groups)


def resolve_env(env_id_or_env: Any, env_params: Any = None) -> tuple[str, Any, Any]:
    """`"LetterLTL0-v0"`, `(env, params)` or an env -> `(env_id, env, params)`."""
    if isinstance(env_id_or_env, str):
        from specrl_jax.envs.registry import make

        env, params = make(env_id_or_env)
        env_id = env_id_or_env
    elif isinstance(env_id_or_env, tuple) and len(env_id_or_env) == 2:
        env, params = env_id_or_env
        env_id = repr(env)
    elif hasattr(env_id_or_env, "reset") and hasattr(env_id_or_env, "step"):
        env, params = env_id_or_env, env_id_or_env.default_params
        env_id = repr(env)
    else:
        raise TypeError(
            f"expected an env ID, an env or a pair (env, params); got {type(env_id_or_env).__name__}"
        )
    return env_id, env, params if env_params is None else env_params


def prepare_specs(env: Any, specs: Any) -> tuple[Any, tuple[str, ...]]:
    """Formulas, CompiledSpecs or a stacked batch -> `(stacked batch, names)`."""
    if isinstance(specs, str):
        raise TypeError(
            "specs must be a list of formulas or compiled specs; for a named suite pass "
            "specrl_jax.specs.suite(name)"
        )
    if hasattr(specs, "delta"):
        if jnp.ndim(specs.delta) != 3:
            raise ValueError("a single CompiledSpec was given; pass a list or a stacked batch")
        return specs, tuple(f"spec{i}" for i in range(int(specs.delta.shape[0])))
    specs = list(specs)
    if not specs:
        raise ValueError("no specs to evaluate")
    if all(isinstance(s, str) for s in specs):
        return automata.compile_suite(specs, env.propositions, env.alphabet), tuple(specs)
    if all(hasattr(s, "delta") for s in specs):
        return automata.stack(specs), tuple(f"spec{i}" for i in range(len(specs)))
    raise TypeError("specs must be all formula strings or all CompiledSpec objects")


def run_episode(policy: StatefulPolicy, task: TaskEnv, params: Any, horizon: int | jax.Array,
                policy_params: Any, key: jax.Array, spec_index: jax.Array,
                record: Callable[[TaskState], Any] | None = None, original: Any = None):
    """One episode of at most `horizon` steps (trace-time function; `vmap` it over lanes).

    `horizon` is an int, or (not with `record`) an int32 scalar traced in a `while` loop.
    `original` (optional): the original benchmark's automata stacked like the task's specs
    (`eval.original_ldba`), tracked beside ours to count accepting visits as the original did.

    Returns:
        `(final TaskState, aborted bool[], trace, original visits int32[] or None)`: `aborted`
        when the policy gave the episode up (see `StatefulPolicy.aborted`); `trace` is None, or
        with `record` a pair of what it returns of each step's TaskState `[T]` (after each step)
        and `alive bool[T]` (the step was part of the episode); the last entry is -1 where the
        spec has no original automaton.
    """
    key_reset, key_init, key_loop = jax.random.split(key, 3)
    obs, state = task.reset(key_reset, params, spec_index)
    carry = policy.init(policy_params, obs, state, key_init)
    ldba = None if original is None else jax.tree.map(lambda x: x[spec_index], original)
    tracker = None if ldba is None else original_ldba.init(ldba)

    def body(loop):
        obs, state, carry, done, aborted, tracker, t = loop
        key_policy, key_step = jax.random.split(jax.random.fold_in(key_loop, t))
        output, carry_next = policy.apply(policy_params, obs, state, carry, key_policy)
        gives_up = ~done & (False if policy.aborted is None else policy.aborted(carry_next))
        action, take_epsilon = split_action(output)
        obs_next, state_next, _, terminated, truncated, info = task.step_task(
            key_step, state, action, params, take_epsilon
        )
        if ldba is not None:
            tracked, _ = original_ldba.step(ldba, tracker, info["propositions"], info["epsilon"])
            tracker = select_tree(done | gives_up, tracker, tracked)
        # An ended episode stays frozen until the loop (the horizon) is over; a given-up one
        # freezes before its step. The spec index is set again after the select so that it stays
        # unbatched over the episodes that share it (and so does every spec read through it).
        obs, state, carry = select_tree(
            done | gives_up, (obs, state, carry), (obs_next, state_next, carry_next)
        )
        state = state.replace(task=state.task.replace(spec_index=state_next.spec_index))
        trace = None if record is None else (record(state), ~done & ~gives_up)
        ended = done | gives_up | terminated | truncated
        return (obs, state, carry, ended, aborted | gives_up, tracker, t + 1), trace

    init = (obs, state, carry, jnp.zeros((), bool), jnp.zeros((), bool), tracker, jnp.int32(0))
    if record is not None:
        final, trace = jax.lax.scan(lambda loop, _: body(loop), init, None, length=horizon)
    else:  # a scan for an int horizon, a while loop for a traced one
        final, trace = jax.lax.fori_loop(0, horizon, lambda _, loop: body(loop)[0], init), None
    (_, state, _, _, aborted, tracker, _) = final
    visits = None if ldba is None else jnp.where(ldba.present, tracker.visits, -1)
    return state, aborted, trace, visits


def make_evaluator(policy: Callable[..., Any] | StatefulPolicy, task: TaskEnv, params: Any,
                   episodes_per_seed: int, horizon: int | None = None,
                   sequential_seeds: bool = False, original: Any = None,
                   devices: Sequence[Any] | None = None, params_per_seed: bool = False
                   ) -> Callable[..., EpisodeTable]:
    """A jitted `fn(policy_params, seeds uint32[num_seeds], spec_indices=None, horizon=None)
    -> EpisodeTable` (device arrays, fields `[num_seeds, K, episodes_per_seed]`); compile once,
    call many times.

    By default the K specs are all the task's specs and every episode runs `horizon` steps
    (default `params.max_steps`; it sets the world's time limit), both fixed at compile time.
    Passing `spec_indices` (int32[K], any K) and `horizon` (an int32 scalar, which also sets
    `max_steps`) makes them arguments: one compiled program then serves groups of specs with
    different horizons.

    `sequential_seeds` runs the seeds one after the other (`lax.map`) instead of side by side,
    dividing peak memory by `num_seeds`, for runs too large for one device. With
    `params_per_seed`, `policy_params` has a leading `num_seeds` axis whose entry i serves seed i
    (one trained run per seed). `original`: the
    original's automata of the task's specs (`original_ldba.stack_ldbas`), counted beside ours
    (`EpisodeTable.num_accepting_original`). Memory holds each episode's running state only,
    whatever the horizon.

    The episodes of a (seed, spec) are sharded over `devices` (default: every local device),
    padded to a multiple of their count, and each device runs its own (`shard_map`); an
    episode's outcome depends on its seed and index only, so the table is the same on any
    number of devices."""
    policy = as_stateful(policy)
    fixed_horizon = int(params.max_steps) if horizon is None else int(horizon)
    params = params.replace(max_steps=fixed_horizon)  # the world's time limit is the horizon
    mesh = Mesh(np.asarray(list(devices) if devices is not None else jax.local_devices()), ("env",))
    padded = -(-episodes_per_seed // mesh.size) * mesh.size
    on_devices = NamedSharding(mesh, PartitionSpec("env"))

    def episode(policy_params, run_params, steps, seed, spec_index, episode_index):
        key = jax.random.fold_in(jax.random.key(seed), episode_index)
        state, aborted, _, visits = run_episode(policy, task, run_params, steps, policy_params,
                                                key, spec_index, original=original)
        return _outcome(state, aborted, visits)

    per_episode = jax.vmap(episode, in_axes=(None, None, None, None, None, 0))
    if mesh.size > 1:  # each device runs its own episodes: foreign calls (MuJoCo Warp) included
        per_episode = _on_each_device(per_episode, mesh)
    per_spec = jax.vmap(per_episode, in_axes=(None, None, None, None, 0, None))

    @jax.jit
    def evaluator(policy_params, seeds, spec_indices=None, horizon=None):
        episodes = jax.lax.with_sharding_constraint(jnp.arange(padded), on_devices)
        if spec_indices is None:
            spec_indices = jnp.arange(task.num_specs)
        if horizon is None:
            run_params, steps = params, fixed_horizon
        else:
            steps = jnp.asarray(horizon, jnp.int32)
            run_params = params.replace(max_steps=steps)

        def one_seed(seed_params, seed):
            return per_spec(seed_params, run_params, steps, seed, spec_indices, episodes)

        if not sequential_seeds:
            table = jax.vmap(one_seed, in_axes=(0 if params_per_seed else None, 0))(policy_params, seeds)
        elif params_per_seed:
            table = jax.lax.map(lambda pair: one_seed(*pair), (policy_params, seeds))
        else:
            table = jax.lax.map(lambda seed: one_seed(policy_params, seed), seeds)
        return jax.tree.map(lambda x: x[:, :, :episodes_per_seed], table)

    return evaluator


def _on_each_device(per_episode: Callable[..., EpisodeTable], mesh: Mesh
                    ) -> Callable[..., EpisodeTable]:
    """`per_episode(policy_params, run_params, steps, seed, spec_index, episodes)` run by each
    device of `mesh` on its share of `episodes` (`shard_map`); an int `steps` stays static."""
    replicated, sharded = PartitionSpec(), PartitionSpec("env")

    def run(policy_params, run_params, steps, seed, spec_index, episodes):
        static = isinstance(steps, int)

        def here(policy_params, run_params, traced_steps, seed, spec_index, episodes):
            horizon = steps if static else traced_steps
            return per_episode(policy_params, run_params, horizon, seed, spec_index, episodes)

        return jax.shard_map(
            here, mesh=mesh, out_specs=sharded, check_vma=False,
            in_specs=(replicated, replicated, replicated, replicated, replicated, sharded),
        )(policy_params, run_params, jnp.int32(0) if static else steps, seed, spec_index, episodes)

    return run


def _outcome(state: TaskState, aborted: jax.Array, visits: jax.Array | None) -> EpisodeTable:
    return EpisodeTable(state.success, state.violation, state.time, state.num_accepting, aborted,
                        visits)


def check_seeds(seeds: Sequence[int]) -> tuple[int, ...]:
    """Seeds as a tuple of distinct ints in [0, 2**32); a clear error otherwise."""
    seeds = tuple(seeds)
    if not seeds:
        raise ValueError("seeds is empty; give at least one integer seed")
    for seed in seeds:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seeds must be integers, got {seed!r}")
        if not 0 <= int(seed) < 2**32:
            raise ValueError(f"seeds must lie in 0 .. 2**32 - 1, got {seed}")
    if len({int(s) for s in seeds}) != len(seeds):
        dupes = sorted({int(s) for s in seeds if list(seeds).count(s) > 1})
        raise ValueError(f"seeds must be distinct (a repeated seed repeats its episodes), got "
                         f"{dupes} more than once")
    return tuple(int(s) for s in seeds)


def evaluate(policy: Callable[..., Any] | StatefulPolicy, env_id_or_env: Any, specs: Any,
             seeds: Sequence[int], episodes_per_seed: int, *, policy_params: Any = None,
             env_params: Any = None, horizon: int | None = None) -> EvalResult:
    """Run `episodes_per_seed` episodes of every spec under every seed, in one compiled call.

    Args:
        policy: a pure function `(policy_params, obs, task_state, key) -> action` (or
            `(action, take_epsilon)`), or a `StatefulPolicy`.
        env_id_or_env: an env ID, an env, or `(env, params)`.
        specs: formula strings, CompiledSpecs, or a stacked batch of K specs.
        seeds: integer seeds; each becomes `jax.random.key(seed)`.
        episodes_per_seed: episodes per (seed, spec), each on a fresh layout.
        policy_params: passed to the policy unchanged (network weights, or None).
        env_params: overrides the env's params (e.g. `max_steps`).
        horizon: episode length in steps, the world's time limit for these episodes
            (`params.max_steps` is replaced); defaults to `params.max_steps`.

    Returns:
        An `EvalResult` with the episode table as numpy arrays.
    """
    seeds = check_seeds(seeds)
    if not isinstance(episodes_per_seed, int) or episodes_per_seed < 1:
        raise ValueError(f"episodes_per_seed must be a positive int, got {episodes_per_seed!r}")
    env_id, env, params = resolve_env(env_id_or_env, env_params)
    stacked, names = prepare_specs(env, specs)
    task = TaskEnv(env, stacked)
    horizon = int(params.max_steps) if horizon is None else int(horizon)
    evaluator = make_evaluator(policy, task, params, episodes_per_seed, horizon)
    table = jax.device_get(evaluator(policy_params, jnp.asarray(seeds, jnp.uint32)))
    return EvalResult(
        env_id=env_id,
        spec_names=names,
        is_finite=np.asarray(stacked.is_finite, bool),
        seeds=seeds,
        episodes_per_seed=episodes_per_seed,
        horizon=horizon,
        table=EpisodeTable(*(None if x is None else np.asarray(x) for x in table)),
    )


def record_episodes(policy: Callable[..., Any] | StatefulPolicy, task: TaskEnv, params: Any,
                    keys: jax.Array, spec_index: jax.Array, policy_params: Any = None,
                    horizon: int | None = None,
                    capture: Callable[[TaskState], Any] | None = None) -> tuple[Any, jax.Array]:
    """TaskStates `[B, T + 1]` (the reset state, then after each step) and `alive bool[B, T + 1]`
    (the state belongs to the episode) of `B` episodes, for plots and checks. `capture` keeps
    only what it returns of each TaskState (a long episode's states hold its spec every step)."""
    policy = as_stateful(policy)
    horizon = int(params.max_steps) if horizon is None else int(horizon)
    params = params.replace(max_steps=horizon)
    keep = capture or (lambda state: state)

    @jax.jit
    def run(keys, spec_index):
        def one(key, index):
            _, _, (states, alive), _ = run_episode(
                policy, task, params, horizon, policy_params, key, index, keep
            )
            _, first = task.reset(jax.random.split(key, 3)[0], params, index)
            first = keep(first)
            states = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, states)
            return states, jnp.concatenate([jnp.ones((1,), bool), alive])

        return jax.vmap(one)(keys, spec_index)

    return run(keys, spec_index)
