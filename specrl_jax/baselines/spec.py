"""The declared interface of a method, and the registry of methods.

A method is one package under `specrl_jax/baselines/` whose `SPEC` is a `MethodSpec`: what it
provides to the training driver (`experiment.train`), to evaluation (`experiment.evaluate`) and to
the command line. Adding a method means one package and one `register_method(SPEC)` (the five
baselines are registered below).
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from specrl_jax.baselines.ppo.train import Method, PPOConfig


def _reference_modes(family: str) -> bool:
    """Mode actions on every world but LetterWorld, where the reference samples them."""
    return family != "letter"


@dataclasses.dataclass(frozen=True)
class MethodSpec:
    """A method, as the benchmark uses it.

    Attributes:
        name: the CLI's name ("genz").
        title: the paper's name ("GenZ-LTL").
        make_method: `(world, params, family, **options) -> Method`, the trainer's method object.
        ppo_config: `(family, **overrides) -> PPOConfig`, the method's training settings.
        make_policy: `(network, alphabet, obs_kinds, deterministic=..., **policy_options)` ->
            the test-time agent (a `tasks.StatefulPolicy`).
        summarise: per-update derived scalars of a metrics row (e.g. success rate).
        policy_options: `(method) -> dict`, `make_policy` options read off the trained method
            object (GCRL-LTL's value network, whose widths are a `make_method` option).
        options: the keyword options `make_method` takes beyond world, params and family.
        deterministic: `(family) -> bool`, the reference's test-time action mode.
        deterministic_infinite: `(family) -> bool`, the reference's action mode on specs that
            are not co-safe, where it differs from `deterministic` (given to `make_policy` as
            `deterministic_infinite`); None: `deterministic` holds for every spec.
        prepare_training: `(method, key, config, log, saved) -> method`, a phase before PPO;
            `saved` (a path in the run directory, or None) keeps its result for a resumed run.
        finish_training: `(method, params, key, config, log, program_key, first_seed) ->
            params`, a phase after PPO, run once PPO reached its last update (a run stopped
            before has the policy's parameters alone and saves none); `program_key` (or None)
            names its traced programs on disk (`compile_log.compile_logged`); the seeds are seeds
            `first_seed` on of a run (`runs.seed_keys`).
        param_shapes: `(method, policy_shapes) -> shapes`, where the saved parameters hold more
            than the PPO network's.
        usable_suites: `(suites, log) -> suites`, the suites the method can be evaluated on.
        policy_takes_suites: whether `make_policy` needs the evaluated suites' names.
        coordinator_agent: `(network, obs_kinds, ...)`, the agent the multi-agent coordinator
            drives, where the method has one.
        pretrain: `(world, family, key, steps, log, **ppo_shape) -> encoder parameters`, where
            the method pretrains a formula encoder (`specrl-jax pretrain`).
        shipped_encoder: `(name) -> Path`, where the package keeps its pretrained encoder of
            that name (`families.encoder_name`).
        encoder_per_symbol: whether the encoder reads alphabet symbols (RAD-Embeddings' DFAs),
            so that a world whose labels can hold several propositions needs its own.
        accelerator_ppo: PPO settings that replace the method's on an accelerator's wide rollout
            (`experiment.default_overrides`; each a departure in docs/fidelity.md).
    """

    name: str
    title: str
    make_method: Callable[..., Method]
    ppo_config: Callable[..., PPOConfig]
    make_policy: Callable[..., Any]
    summarise: Callable[[dict[str, float]], dict[str, float]]
    options: tuple[str, ...] = ()
    policy_options: Callable[[Method], dict[str, Any]] | None = None
    deterministic: Callable[[str], bool] = _reference_modes
    deterministic_infinite: Callable[[str], bool] | None = None
    prepare_training: Callable[..., Method] | None = None
    finish_training: Callable[..., Any] | None = None
    param_shapes: Callable[..., Any] | None = None
    usable_suites: Callable[[Sequence[str], Callable[[str], None]], list[str]] | None = None
    policy_takes_suites: bool = False
    coordinator_agent: Callable[..., Any] | None = None
    pretrain: Callable[..., Any] | None = None
    shipped_encoder: Callable[[str], Path] | None = None
    encoder_per_symbol: bool = False
    accelerator_ppo: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def check_options(self, options: dict[str, Any] | None) -> None:
        """A ValueError naming the options this method does not take, listing those it does."""
        unknown = sorted(set(options or {}) - set(self.options))
        if unknown:
            raise ValueError(f"{self.title} has no option {', '.join(map(repr, unknown))}; "
                             f"accepted: {', '.join(self.options)}")


_METHODS: dict[str, MethodSpec] = {}


def register_method(spec: MethodSpec) -> None:
    """Make a method known to the training driver, evaluation and the command line."""
    if spec.name in _METHODS:
        raise ValueError(f"method {spec.name!r} is already registered")
    _METHODS[spec.name] = spec


def unregister_method(name: str) -> None:
    _METHODS.pop(name, None)


def list_methods() -> list[str]:
    _register_baselines()
    return list(_METHODS)


def get_method(name: str) -> MethodSpec:
    """The specification of a registered method, with a clear error for an unknown name."""
    _register_baselines()
    if name not in _METHODS:
        close = difflib.get_close_matches(str(name), list(_METHODS), n=3)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise ValueError(f"unknown method {name!r}; accepted: {', '.join(_METHODS)}.{hint}")
    return _METHODS[name]


_BASELINES = ("genz", "deepltl", "ltl2action", "gcrl", "rad")


def _register_baselines() -> None:
    """Register the five baselines on first use (importing them builds flax modules)."""
    if all(name in _METHODS for name in _BASELINES):
        return
    import importlib

    for name in _BASELINES:
        if name not in _METHODS:
            register_method(importlib.import_module(f"specrl_jax.baselines.{name}").SPEC)
