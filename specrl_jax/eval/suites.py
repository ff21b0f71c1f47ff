"""Evaluating a policy on named suites: compiles them (`automata.compile_suite`), groups them by
episode horizon and splits the result back into one `SuiteResult` per suite.

Finite suites run the world's horizon (`params.max_steps`); infinite ones
`SuiteInfo.horizon_factor` times it (10: LetterWorld 750, Zone 10,000 steps), unless `horizon`
overrides both. Memory stays bounded at any horizon: the evaluator keeps each episode's running
counts, never per-step arrays.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, specs
from specrl_jax.eval import original_ldba
from specrl_jax.eval.evaluate import EvalResult, check_seeds, make_evaluator
from specrl_jax.eval.metrics import EpisodeTable
from specrl_jax.eval.report import SuiteResult
from specrl_jax.tasks import TaskEnv


def suite_horizon(name: str, finite_horizon: int, horizon: int | None = None,
                  infinite_horizon: int | None = None) -> int:
    """Episode length for suite `name` in a world whose finite horizon is `finite_horizon`;
    `horizon` overrides every suite's, `infinite_horizon` only the infinite suites'."""
    if horizon is not None:
        return int(horizon)
    info = specs.suite_info(name)
    if infinite_horizon is not None and not info.is_finite:
        return int(infinite_horizon)
    return int(finite_horizon) * info.horizon_factor


def check_suites(names: Sequence[str], env: Any) -> None:
    """Raise a clear error for a suite over propositions the world does not have."""
    for name in names:
        info = specs.suite_info(name)
        if not set(info.propositions) <= set(env.propositions):
            raise ValueError(f"suite {name!r} is over propositions {info.propositions}, but the "
                             f"env has {env.propositions}")


def originals(formulas: Sequence[str], env: Any) -> Any:
    """The original benchmark's automata of `formulas` (stacked, `eval.original_ldba`), or None
    when none of them has one (only the paper's infinite-horizon formulas do)."""
    texts = [original_ldba.original_hoa(f) for f in formulas]
    if all(t is None for t in texts):
        return None
    alphabet = np.asarray(env.alphabet, bool)
    return original_ldba.stack_ldbas(
        [None if t is None else original_ldba.build_ldba(t, env.propositions, alphabet)
         for t in texts], alphabet)


def evaluate_suites(policy: Any, env_id: str, env: Any, params: Any, suites: Sequence[str],
                    episodes: int, seeds: Sequence[int], policy_params: Any = None,
                    params_per_seed: bool = False, horizon: int | None = None,
                    infinite_horizon: int | None = None, label: str = "",
                    log: Callable[[str], None] = print,
                    devices: Sequence[Any] | None = None) -> list[SuiteResult]:
    """Evaluate `policy` on every suite; one compiled program runs each group of suites that
    share a horizon (the specs and the horizon are its arguments). `compile_suites`, then run
    on `policy_params`.

    Args:
        policy: a policy function or `StatefulPolicy` (see `tasks.policy`).
        env_id, env, params: the world (the horizon comes from `params.max_steps`).
        suites: suite names; episodes: per (seed, spec); seeds: integer seeds.
        policy_params: passed to the policy; with `params_per_seed`, a pytree with a leading
            axis of `len(seeds)` whose entry i serves seed i (one trained run per seed).
        horizon: overrides every suite's horizon; infinite_horizon: only the infinite suites'.
        label: the method name in the reports.
        devices: the episodes are sharded over these (default: every local device).

    Returns:
        One `SuiteResult` per suite, in the order given.
    """
    return compile_suites(policy, env_id, env, params, suites, episodes, seeds, policy_params,
                          params_per_seed, horizon, infinite_horizon, label, log, devices)(policy_params)


def compile_suites(policy: Any, env_id: str, env: Any, params: Any, suites: Sequence[str],
                   episodes: int, seeds: Sequence[int], policy_params: Any = None,
                   params_per_seed: bool = False, horizon: int | None = None,
                   infinite_horizon: int | None = None, label: str = "",
                   log: Callable[[str], None] = print,
                   devices: Sequence[Any] | None = None) -> Callable[[Any], list[SuiteResult]]:
    """`evaluate_suites`' program compiled now for parameters shaped as `policy_params` (arrays,
    or `jax.ShapeDtypeStruct`s: compiled before the parameters exist, e.g. while they train);
    the returned function evaluates parameters of those shapes, placed as the program takes
    them."""
    check_suites(suites, env)
    seeds = check_seeds(seeds)
    by_horizon: dict[int, list[str]] = {}
    for name in suites:
        by_horizon.setdefault(suite_horizon(name, params.max_steps, horizon, infinite_horizon), []).append(name)
    seed_array = jnp.asarray(seeds, jnp.uint32)
    formulas, groups = [], []  # groups: (horizon, spec indices, {suite: spec indices})
    for steps, names in by_horizon.items():
        start, indices = len(formulas), {}
        for name in names:
            indices[name] = list(range(len(formulas), len(formulas) + len(specs.suite(name))))
            formulas += specs.suite(name)
        groups.append((steps, list(range(start, len(formulas))), indices))
    compiled = automata.compile_suite(formulas, env.propositions, env.alphabet)
    # One program for every horizon: the group's specs and its horizon are arguments, each
    # group padded to the largest by repeating its last spec. A lone group keeps its horizon
    # fixed at compile time (a scan, faster than the while loop of a traced horizon).
    width = max(len(group_specs) for _, group_specs, _ in groups)
    evaluator = make_evaluator(policy, TaskEnv(env, compiled),
                               params.replace(max_steps=groups[0][0]), episodes_per_seed=episodes,
                               original=originals(formulas, env), params_per_seed=params_per_seed,
                               devices=devices)

    def arguments(policy_params: Any, steps: int, group_specs: list[int]) -> tuple:
        padded = group_specs + group_specs[-1:] * (width - len(group_specs))
        horizon_argument = None if len(groups) == 1 else jnp.int32(steps)
        return policy_params, seed_array, jnp.asarray(padded, jnp.int32), horizon_argument

    start = time.perf_counter()
    executable = evaluator.lower(*arguments(policy_params, *groups[0][:2])).compile()
    log(f"compiled the evaluator in {time.perf_counter() - start:.1f}s")

    def evaluate(policy_params: Any) -> list[SuiteResult]:
        policy_params = jax.device_put(policy_params, executable.input_shardings[0][0])
        results = {}
        for steps, group_specs, indices in groups:
            start = time.perf_counter()
            out = jax.device_get(executable(*arguments(policy_params, steps, group_specs)))
            table = EpisodeTable(*(None if x is None else np.asarray(x)[:, :len(group_specs)]
                                   for x in out))
            if table.num_accepting_original is not None and (table.num_accepting_original < 0).all():
                table = table._replace(num_accepting_original=None)  # no spec of the group has one
            log(f"evaluated {len(seeds)} seeds x {len(group_specs)} specs x {episodes} episodes x "
                f"{steps} steps in {time.perf_counter() - start:.1f}s")
            result = EvalResult(
                env_id=env_id, spec_names=tuple(formulas[i] for i in group_specs),
                is_finite=np.asarray(compiled.is_finite)[group_specs],
                seeds=tuple(int(s) for s in seeds), episodes_per_seed=episodes, horizon=steps,
                table=table,
            )
            for name, spec_indices in indices.items():
                local = [i - group_specs[0] for i in spec_indices]
                results[name] = SuiteResult(env_id, name, label, result.select(local))
        return [results[name] for name in suites]

    return evaluate
