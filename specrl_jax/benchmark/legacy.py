"""Scoring a policy that lives outside JAX (numpy, PyTorch) through the Gymnasium bridge.

`evaluate(policy_fn, env_id, suites, episodes, seeds)` runs the same episodes as the JAX
evaluator (`eval.evaluate`): episode (seed s, spec k, episode e) starts its world from the key the
JAX evaluator uses, so both see the same layouts, and the automaton takes the task source's step
(`automata.step_in_batch`) on the labels the Gymnasium vector env reports. The world is stepped by
`specrl_jax.gym.GymVectorEnv` (the original benchmark's observation layout, numpy in and out) and
the policy is a plain callable:

    actions = policy_fn(obs, task)     # obs: numpy [N, ...], the original's layout
                                       # task: a `LegacyTask` of N episodes; actions: numpy [N, ...]

Episodes run in waves of `num_envs` side by side. Differences from the JAX backend: the world's
step keys are the vector env's own (LetterWorld and the zone worlds do not draw on them; a world
with step noise gives other draws), and epsilon transitions are not offered (the vector env steps
every world on every call).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, specs
from specrl_jax.eval.evaluate import EvalResult, check_seeds
from specrl_jax.eval.metrics import EpisodeTable
from specrl_jax.eval.report import SuiteResult
from specrl_jax.eval.suites import check_suites, suite_horizon

#: episodes stepped side by side by default
DEFAULT_NUM_ENVS = 2048


class LegacyTask(NamedTuple):
    """What a legacy policy reads beside the observation, one row per episode of the wave (N).

    `formulas`: the episode's formula text; `spec_index` int32[N]: its row in the evaluated
    suites; `q` int32[N]: the automaton state (`automata.compile_spec(formula, ...)` numbers the
    states as the benchmark does); `propositions` bool[N, P]: the last label (all False at the
    first step), columns in `proposition_names` order; `time` int32[N]: steps so far;
    `first` bool[N]: the episode's first step (reset a recurrent policy's memory there).
    """

    formulas: tuple[str, ...]
    spec_index: np.ndarray
    q: np.ndarray
    propositions: np.ndarray
    time: np.ndarray
    first: np.ndarray
    proposition_names: tuple[str, ...]


def _reset_key(seed: jax.Array, episode: jax.Array) -> jax.Array:
    key = jax.random.fold_in(jax.random.key(seed), episode)
    key_reset = jax.random.split(key, 3)[0]
    return jax.random.split(key_reset)[0]


_reset_keys = jax.jit(jax.vmap(_reset_key))


def episode_reset_keys(seeds: np.ndarray, episodes: np.ndarray) -> jax.Array:
    """The world-reset keys the JAX evaluator uses for episodes `(seeds[i], episodes[i])`
    (`eval.evaluate.run_episode`, then `TaskEnv.reset`)."""
    return _reset_keys(jnp.asarray(seeds, jnp.uint32), jnp.asarray(episodes))


@jax.jit
def _initial_states(compiled: Any, index: jax.Array) -> jax.Array:
    """int32[N]: each episode's initial automaton state (`AutomatonSource.reset`)."""
    return compiled.init[index].astype(jnp.int32)


@jax.jit
def _step_automata(compiled: Any, index: jax.Array, q: jax.Array, label: jax.Array) -> tuple:
    """One automaton step per episode on its label, as `AutomatonSource.step` (no epsilon):
    `(q, accepted, success, violation)`, success only for finite-horizon specs."""

    def one(spec_index, state, props):
        q_next, accepted, success, violation = automata.step_in_batch(
            compiled, spec_index, state, props, jnp.int32(-1), None)
        return q_next, accepted, success & compiled.is_finite[spec_index], violation

    return jax.vmap(one)(index, q, label)


@functools.lru_cache(maxsize=8)
def _vector_env(env_id: str, num_envs: int) -> Any:
    """One Gymnasium vector env per (world, width) in a process: its programs compile once."""
    import specrl_jax.gym as gym_bridge

    return gym_bridge.GymVectorEnv(env_id, num_envs=num_envs)


def evaluate(policy_fn: Callable[[Any, LegacyTask], Any], env_id: str, suites: Sequence[str],
             episodes: int, seeds: Sequence[int], horizon: int | None = None,
             num_envs: int | None = None, label: str = "policy",
             log: Callable[[str], None] = print) -> list[SuiteResult]:
    """Evaluate a numpy policy on `suites` of `env_id` through the Gymnasium vector env.

    Args:
        policy_fn: `(obs numpy [N, ...], LegacyTask) -> actions numpy [N, ...]`.
        env_id: a single-agent env ID; suites: suite names over its propositions.
        episodes: per (seed, spec); seeds: integer seeds (the JAX evaluator's).
        horizon: overrides every suite's episode length (as `eval.suites.evaluate_suites`).
        num_envs: episodes stepped side by side (default `DEFAULT_NUM_ENVS` or fewer).
        label: the policy's name in the reports.

    Returns:
        One `SuiteResult` per suite, with the JAX backend's metrics.
    """
    from specrl_jax.envs.registry import make

    world, params = make(env_id)
    if hasattr(world, "agents"):
        raise ValueError(f"the gymnasium backend scores single-agent worlds; {env_id} has agents")
    check_suites(suites, world)
    seeds = check_seeds(seeds)
    names_by_horizon: dict[int, list[str]] = {}
    for name in suites:
        steps = suite_horizon(name, params.max_steps, horizon)
        names_by_horizon.setdefault(steps, []).append(name)
    # one vector env (one compiled step) for every group: as wide as the largest needs
    lanes = max(len(seeds) * sum(len(specs.suite(n)) for n in names) * episodes
                for names in names_by_horizon.values())
    vec = _vector_env(env_id, min(num_envs or DEFAULT_NUM_ENVS, lanes))
    results = {}
    for steps, names in names_by_horizon.items():
        formulas = [f for name in names for f in specs.suite(name)]
        compiled = automata.compile_suite(formulas, world.propositions, world.alphabet)
        vec.params = params.replace(max_steps=steps)
        start = time.perf_counter()
        table = _run(policy_fn, vec, compiled, formulas, seeds, episodes, steps)
        log(f"gymnasium backend: {len(seeds)} seeds x {len(formulas)} specs x {episodes} episodes"
            f" x {steps} steps in {time.perf_counter() - start:.1f}s")
        result = EvalResult(env_id=env_id, spec_names=tuple(formulas),
                            is_finite=np.asarray(compiled.is_finite, bool), seeds=seeds,
                            episodes_per_seed=episodes, horizon=steps, table=table)
        offset = 0
        for name in names:
            count = len(specs.suite(name))
            results[name] = SuiteResult(env_id, name, label,
                                        result.select(range(offset, offset + count)))
            offset += count
    return [results[name] for name in suites]


def _run(policy_fn: Callable, vec: Any, compiled: Any, formulas: Sequence[str],
         seeds: Sequence[int], episodes: int, horizon: int) -> EpisodeTable:
    """Every (seed, spec, episode) in waves of `vec.num_envs`; the table `[S, K, E]`."""
    num_specs = len(formulas)
    grid = np.stack(np.meshgrid(np.arange(len(seeds)), np.arange(num_specs), np.arange(episodes),
                                indexing="ij"), axis=-1).reshape(-1, 3)  # lanes: (seed, spec, ep)
    width = vec.num_envs
    out = {name: np.zeros(len(grid), dtype) for name, dtype in
           (("success", bool), ("violation", bool), ("steps", np.int32), ("accepting", np.int32))}
    seed_values = np.asarray(seeds, np.uint32)
    for begin in range(0, len(grid), width):
        wave = grid[begin:begin + width]
        count = len(wave)
        wave = np.concatenate([wave, np.repeat(wave[-1:], width - count, axis=0)])
        keys = episode_reset_keys(seed_values[wave[:, 0]], wave[:, 2])
        obs, _ = vec.reset(options={"keys": keys})
        index = jnp.asarray(wave[:, 1], jnp.int32)
        q = _initial_states(compiled, index)
        outcome = _run_wave(policy_fn, vec, obs, compiled, index, q, formulas, horizon)
        for name, values in outcome.items():
            out[name][begin:begin + count] = values[:count]
    shape = (len(seeds), num_specs, episodes)
    return EpisodeTable(out["success"].reshape(shape), out["violation"].reshape(shape),
                        out["steps"].reshape(shape), out["accepting"].reshape(shape),
                        np.zeros(shape, bool))


def _run_wave(policy_fn: Callable, vec: Any, obs: Any, compiled: Any, index: jax.Array,
              q: jax.Array, formulas: Sequence[str], horizon: int) -> dict[str, np.ndarray]:
    """One wave of `vec.num_envs` episodes from their first observation `obs`; an episode stops
    counting once it ends (its world may run on, its steps are not read)."""
    width = vec.num_envs
    alive = np.ones(width, bool)
    success, violation = np.zeros(width, bool), np.zeros(width, bool)
    steps, accepting = np.zeros(width, np.int32), np.zeros(width, np.int32)
    label = np.zeros((width, len(vec.propositions)), bool)
    index_np = np.asarray(index)
    lane_formulas = tuple(formulas[i] for i in index_np)
    for t in range(horizon):
        task = LegacyTask(lane_formulas, index_np, np.asarray(q), label, steps.copy(),
                          np.full(width, t == 0), tuple(vec.propositions))
        actions = policy_fn(obs, task)
        if isinstance(actions, tuple):
            raise TypeError("the gymnasium backend takes actions only, not (action, take_epsilon) "
                            "pairs: it does not offer epsilon transitions")
        obs, _, terminated, _, info = vec.step(np.asarray(actions))
        label = np.asarray(info["propositions"], bool)
        q_next, accepted, done_success, done_violation = jax.device_get(
            _step_automata(compiled, index, q, jnp.asarray(label)))
        steps += alive
        accepting += alive & accepted
        success |= alive & done_success
        violation |= alive & done_violation
        q = jnp.where(jnp.asarray(alive), q_next, q)
        alive &= ~(done_success | done_violation | terminated)
        if not alive.any():
            break
    return {"success": success, "violation": violation, "steps": steps, "accepting": accepting}
