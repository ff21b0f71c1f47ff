"""LTL2Action (Vaezipoor et al., ICML'21): policies conditioned on the progressed LTL formula.

The task loop runs a progression source: each episode draws a formula from a bank, and every
label progresses it; +1 and the end of the episode when it progresses to true, -1 and the end
when it progresses to false. The bank holds (the family record's task source) the world's DeepLTL curriculum as
formulas, whose stages advance on the agent's success (LetterWorld, ZoneEnv;
`tasks.curriculum_progression`), or draws of one of the original's samplers (`Until_1_3_1_2`,
`Eventually_1_5_1_4`, `Until_1_2_1_1`, ...; the arm). The network reads the current formula's
syntax tree through a relational GCN (`RGCNEncoder`: 8 rounds of one shared relational
convolution over 4 edge types, hidden 32, readout at the root, 32-d embedding; run once over the
bank's distinct subtrees and gathered by state where that is fewer nodes than the samples' trees,
`networks.embed_formulas`), concatenated with the observation embedding, into
an actor [64, 64, 64] ReLU and a critic [64, 64] Tanh. Dense layers start as the original's:
normal weights with each unit's weight vector of unit norm, zero biases. The encoder can start
from parameters pretrained on the symbol task (the original's optional LTLBootcamp,
`ltl2action.pretrain`; `make_method(pretrain_steps=...)` runs it before PPO) and stay frozen
(`freeze_encoder`). At test time (`make_policy`) the agent progresses the
evaluated formula itself.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, families, specs
from specrl_jax.baselines.encoders import obs_parts
from specrl_jax.baselines.ltl2action import pretrain
from specrl_jax.baselines.ltl2action.networks import (
    FormulaGraphs,
    FormulaObs,
    LTL2ActionNetwork,
    network_for,
    with_encoder,
)
from specrl_jax.baselines.params_io import kept_params
from specrl_jax.baselines.ppo.train import Method, PPOConfig, world_config
from specrl_jax.baselines.pretraining import SymbolWorld, run_pretraining
from specrl_jax.baselines.spec import MethodSpec
from specrl_jax.baselines.task_sources import curriculum_of, families_with_curriculum, task_source
from specrl_jax.baselines.train_env import TaskTrainEnv, pass_world_reward
from specrl_jax.specs import CurriculumSampler
from specrl_jax.tasks import StatefulPolicy, TaskEnv
from specrl_jax.tasks.curriculum_progression import CurriculumProgressionSource, stage_formulas
from specrl_jax.tasks.progression import (
    ProgressionBank,
    ProgressionSource,
    build_bank,
    step_state,
)

#: the suites whose formulas the test-time agent recognises unless told otherwise
DEFAULT_SUITES = families.LETTER.suites + families.ZONE.suites


@dataclasses.dataclass(frozen=True)
class LTL2Action(Method):
    """The LTL2Action method for the shared trainer: the task loop over a progression source
    (task params: the curriculum state where the source follows a curriculum, else None)."""

    env: TaskTrainEnv
    network: nn.Module
    encoder: Any = None  # pretrained R-GCN parameters the network starts from, or None
    pretrain_steps: int = 0  # symbol-task steps `prepare_training` pretrains the encoder for
    family: str = "letter"
    formulas: tuple[str, ...] = ()  # the training bank's formulas

    @property
    def bank(self) -> ProgressionBank:
        return self.env.task.source.bank

    @property
    def follows_curriculum(self) -> bool:
        return isinstance(self.env.task.source, CurriculumProgressionSource)

    @property
    def stages(self) -> tuple[int, ...] | None:
        """The sizes of the curriculum stages over `formulas`, in order (None: no curriculum)."""
        if not self.follows_curriculum:
            return None
        return tuple(int(size) for size in np.asarray(self.env.task.source.stages.size))

    def init_params(self, key: jax.Array, obs: FormulaObs) -> Any:
        """The network's initial parameters, with the pretrained encoder where there is one."""
        params = self.network.init(key, obs)
        return params if self.encoder is None else with_encoder(params, self.encoder)

    def init_task_params(self) -> Any:
        return self.env.task.source.init_params()

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        if not self.follows_curriculum:
            return task_params
        return self.env.task.source.update_params(task_params, stats)

    def task_metrics(self, task_params: Any) -> dict[str, jax.Array]:
        if not self.follows_curriculum:
            return {}
        return {"curriculum_stage": task_params.stage.astype(jnp.float32)}


def check_sampler(family: str, sampler: str | None) -> str:
    """`sampler` (default: the family record's task source: "curriculum" where it is a
    curriculum, else the original sampler it names) after checking it names "curriculum" for a
    family with one, or an original sampler.

    Raises:
        ValueError: an unknown family or sampler name, or "curriculum" for the arm.
    """
    source = task_source("ltl2action", family)
    if source is None:
        raise ValueError(f"unknown world family {family!r}; accepted: "
                         f"{', '.join(f for f in families.list_families() if task_source('ltl2action', f))}")
    if sampler is None:
        sampler = "curriculum" if curriculum_of("ltl2action", family) else source
    if sampler == "curriculum" and curriculum_of("ltl2action", family) is None:
        raise ValueError(f"the {family!r} family has no curriculum (families with one: "
                         f"{', '.join(families_with_curriculum('ltl2action'))}); give an original "
                         "sampler such as 'Until_1_2_1_1'")
    if sampler != "curriculum":
        specs.ltl2action_sampler(sampler)  # validates the name
    return sampler


def training_formulas(propositions: Sequence[str], family: str = "letter", num_formulas: int = 1024,
                      seed: int = 0, sampler: str | None = None) -> list[list[str]]:
    """The training bank's formula texts by curriculum stage (host, seeded): for `sampler`
    "curriculum" (default: the family's task source) every task of an enumerated stage and
    `num_formulas` draws of a sampled one; for an original sampler name one list of
    `num_formulas` draws."""
    sampler = check_sampler(family, sampler)
    if num_formulas < 1:
        raise ValueError(f"num_formulas must be >= 1, got {num_formulas}")
    if sampler == "curriculum":
        curriculum = CurriculumSampler(specs.curriculum(curriculum_of("ltl2action", family)), len(propositions))
        return stage_formulas(curriculum, propositions, num_formulas, seed)
    draw = specs.ltl2action_sampler(sampler)
    rng = np.random.default_rng(seed)
    return [[draw(rng, tuple(propositions)) for _ in range(num_formulas)]]


def observe_formula(bank: ProgressionBank, obs_kinds: Mapping[str, str]):
    """`observe(world_obs, task_state) -> FormulaObs` for a progression task loop."""
    kinds = dict(obs_kinds)
    graphs = FormulaGraphs(bank)

    def observe(obs, state):
        return FormulaObs(obs_parts(obs, kinds), state.task.state, graphs)

    return observe


_BANKS: dict[tuple, ProgressionBank] = {}


def make_method(world: Any, params: Any, family: str | None = None,
                formulas: Sequence[str] | None = None,
                num_formulas: int = 1024, seed: int = 0, sampler: str | None = None,
                encoder: Any = None, freeze_encoder: bool = False, pretrain_steps: int = 0,
                stages: Sequence[int] | None = None, network: nn.Module | None = None,
                image_dtype: str = "float32") -> LTL2Action:
    """LTL2Action on any single-agent world, progressed on the device: the given `formulas`
    (drawn uniformly, or by curriculum stages of sizes `stages`), or `training_formulas(...,
    sampler)` (default: the family's task source; a curriculum's stages advance on the episodes'
    success).

    `encoder`: pretrained R-GCN parameters (or the path of a file saved by
    `pretrain.save_encoder`) the network starts from; `freeze_encoder` keeps the R-GCN
    fixed in training (the original's `--freeze-ltl`); `pretrain_steps` > 0 (without `encoder`)
    has `prepare_training` pretrain it on the symbol task over the same formulas first (the
    original's LTLBootcamp, `--pretrained-gnn`); `network` replaces the LTL2Action network;
    `image_dtype`: the image CNN's convolutions (of the LTL2Action network; a given `network`
    keeps its own).
    """
    family = families.name_of(world, family)
    if pretrain_steps < 0:
        raise ValueError(f"pretrain_steps must be >= 0, got {pretrain_steps}")
    if formulas is None:
        by_stage = training_formulas(world.propositions, family, num_formulas, seed, sampler)
        formulas = [f for stage in by_stage for f in stage]
        if check_sampler(family, sampler) == "curriculum":
            stages = [len(stage) for stage in by_stage]
    if isinstance(encoder, (str, os.PathLike)):
        encoder = pretrain.load_encoder(encoder, len(world.propositions))
    network = network_for(world, freeze_encoder, image_dtype) if network is None else network
    alphabet = np.asarray(world.alphabet, bool)
    key = (tuple(formulas), tuple(world.propositions), alphabet.tobytes(), alphabet.shape)
    if key not in _BANKS:  # training, evaluation and loading each build the method once
        _BANKS[key] = build_bank(formulas, world.propositions, alphabet)
    bank = _BANKS[key]
    if stages is None:
        source = ProgressionSource(bank, world.alphabet)
    else:
        curriculum = CurriculumSampler(specs.curriculum(curriculum_of("ltl2action", family)), len(world.propositions))
        source = CurriculumProgressionSource(bank, world.alphabet, curriculum, stages)

    def signals(info):
        return pass_world_reward(info), jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    task = TaskEnv(world, source, observe_formula(bank, world.obs_kinds))
    return LTL2Action(TaskTrainEnv(task, params, signals), network, encoder, pretrain_steps,
                      family, tuple(formulas))


def make_bootcamp(alphabet: np.ndarray, propositions: tuple[str, ...], formulas: Sequence[str],
                  stages: Sequence[int] | None = None, family: str = "letter") -> LTL2Action:
    """The LTLBootcamp symbol task over `alphabet`'s non-empty rows (bool[A, P]) on `formulas`
    (by curriculum stages of sizes `stages`, as `make_method` draws them)."""
    alphabet = np.asarray(alphabet, bool)
    letters = alphabet[alphabet.any(axis=1)]
    if letters.shape[0] == 0:
        raise ValueError("the alphabet has no non-empty assignment to act with")
    world = SymbolWorld(letters, tuple(propositions), pretrain.HORIZON)
    network = pretrain.BootcampNetwork(tuple(propositions), int(letters.shape[0]))
    return make_method(world, world.default_params, family, formulas=formulas, stages=stages,
                       network=network)


def pretrain_encoder(alphabet: np.ndarray, propositions: tuple[str, ...], formulas: Sequence[str],
                     stages: Sequence[int] | None, family: str, key: jax.Array, steps: int,
                     log: Callable[[str], None] = print, chunk_updates: int = 50,
                     **ppo_overrides: Any) -> Any:
    """Pretrain the R-GCN on the symbol task for about `steps` env steps (whole updates of
    `pretrain.bootcamp_config(**ppo_overrides)`, at least one); returns
    `pretrain.encoder_params` of the result."""
    method = make_bootcamp(alphabet, propositions, formulas, stages, family)
    config = pretrain.bootcamp_config(total_timesteps=max(int(steps), 1), **ppo_overrides)
    params = run_pretraining(method, config, key, "LTL bootcamp", log, chunk_updates)
    return pretrain.encoder_params(params)


def pretrain_for_world(world: Any, family: str, key: jax.Array, steps: int,
                       log: Callable[[str], None] = print, num_formulas: int = 1024, seed: int = 0,
                       sampler: str | None = None, **ppo_shape: Any) -> Any:
    """LTLBootcamp on `world`'s alphabet over the formulas the method trains on in `family` (its
    curriculum by stages, or draws of `sampler`); returns the R-GCN's parameters."""
    by_stage = training_formulas(world.propositions, family, num_formulas, seed, sampler)
    formulas = [f for stage in by_stage for f in stage]
    stages = ([len(s) for s in by_stage] if check_sampler(family, sampler) == "curriculum"
              else None)
    return pretrain_encoder(np.asarray(world.alphabet), tuple(world.propositions), formulas,
                            stages, family, key, steps, log, **ppo_shape)


def prepare_training(method: LTL2Action, key: jax.Array, config: PPOConfig,
                     log: Callable[[str], None] = print, saved: Path | None = None
                     ) -> LTL2Action:
    """Before PPO: with `pretrain_steps` and no encoder yet, pretrain the R-GCN on the symbol
    task over the method's training formulas (one encoder for every seed, as the original
    transfers one) and return the method starting from it. `saved`: the encoder's file in the
    run directory, read when there (a resumed run), else written."""
    if method.pretrain_steps <= 0 or method.encoder is not None:
        return method
    world = method.env.task.env
    encoder = kept_params(saved, lambda: pretrain_encoder(
        np.asarray(world.alphabet), tuple(world.propositions), method.formulas, method.stages,
        method.family, jax.random.fold_in(key, 7), method.pretrain_steps, log),
        what="pretrained encoder", log=log)
    return dataclasses.replace(method, encoder=encoder)


def summarise(row: dict[str, float]) -> dict[str, float]:
    episodes = max(row["episodes"], 1.0)
    return {**row, "success_rate": row["successes"] / episodes,
            "violation_rate": row["violations"] / episodes}


def ppo_config(world: str = "letter", **overrides: Any) -> PPOConfig:
    """LTL2Action's settings (`src/README.md`): LetterWorld 16 x 128, minibatch 256, 4 epochs,
    gamma 0.94, entropy 0.01; ZoneEnv 16 x 4096, minibatch 2048, 10 epochs, gamma 0.998, entropy
    0.003; lr 3e-4, GAE 0.95, clip 0.2. The arm (no original setting) takes ZoneEnv's with
    gamma 0.99 and 16 x 1024."""
    return world_config(world, {"update_epochs": 4 if world == "letter" else 10, "loss": "ppo",
                                "vf_coef": 0.5, "gae_lambda": 0.95, "lr": 3e-4}, **overrides)


# ---------------------------------------------------------------------------------------------
# Test time: the agent progresses the evaluated formula itself


class ProgressionCarry(NamedTuple):
    state: jax.Array  # int32[], formula state in the policy's own bank
    time: jax.Array  # int32[], the task step the state describes


def _same_automaton(spec: Any, stacked: Any, k: int) -> bool:
    """The compiled spec `spec` equals entry `k` of a padded stack on its own states."""
    num_states, num_symbols = np.asarray(spec.delta).shape
    delta = np.asarray(stacked.delta[k])
    if delta.shape[1] != num_symbols or delta.shape[0] < num_states:
        return False
    fields = ("delta", "accepting", "success", "violation")
    same_fields = all(np.array_equal(np.asarray(getattr(stacked, f)[k])[:num_states],
                                     np.asarray(getattr(spec, f))) for f in fields)
    return (same_fields and int(stacked.init[k]) == int(spec.init)
            and bool(stacked.is_finite[k]) == bool(spec.is_finite))


def match_formulas(stacked: Any, candidates: Sequence[str], propositions: Sequence[str],
                   alphabet: np.ndarray) -> list[str]:
    """The formula text of each spec of a stacked bank, found among `candidates` by compiling
    them (Spot, cached) and comparing automata; candidates are tried from the one after the last
    match, so banks stacked in candidate order match in one pass.

    Raises:
        ValueError: a spec that no candidate compiles to.
    """
    compiled: dict[str, Any] = {}
    found, start = [], 0
    for k in range(int(stacked.delta.shape[0])):
        for offset in range(len(candidates)):
            i = (start + offset) % len(candidates)
            text = candidates[i]
            if text not in compiled:
                compiled[text] = automata.compile_spec(text, propositions, alphabet=alphabet)
            if _same_automaton(compiled[text], stacked, k):
                found.append(text)
                start = i + 1
                break
        else:
            raise ValueError(
                f"spec {k} of the evaluated bank is none of the {len(candidates)} candidate "
                "formulas; give the evaluated formulas to make_policy (formulas=... or suites=...)")
    return found


def make_policy(network: LTL2ActionNetwork, alphabet: jax.Array, obs_kinds: Mapping[str, str],
                deterministic: bool = False, formulas: Sequence[str] | None = None,
                suites: Sequence[str] | None = None) -> StatefulPolicy:
    """LTL2Action's test-time agent as a `StatefulPolicy` for `specrl_jax.eval.evaluate`.

    The task loop runs an `AutomatonSource` over the evaluated specs (for the success and
    violation flags); the agent recognises each spec's formula among `formulas` (default: those
    of `suites`, default `DEFAULT_SUITES` over the world's propositions), builds their
    progression bank once per evaluated bank (at trace time) and carries the progressed formula,
    stepping it on every new label. Actions are sampled, or the mode where `deterministic`.
    """
    alphabet_np = np.asarray(alphabet, bool)
    props = network.propositions
    kinds = dict(obs_kinds)
    if formulas is None:
        names = [s for s in (suites or DEFAULT_SUITES)
                 if set(specs.suite_info(s).propositions) <= set(props)]
        formulas = [f for s in names for f in specs.suite(s)]
    candidates = list(dict.fromkeys(formulas))
    if not candidates:
        raise ValueError(f"no candidate formulas over the propositions {props}")
    banks: dict[Any, tuple[ProgressionBank, FormulaGraphs]] = {}

    def bank_for(task_state) -> tuple[ProgressionBank, FormulaGraphs]:
        spec_bank = task_state.task.bank
        if spec_bank not in banks:
            # host work at trace time: compile and compare concrete arrays, stage nothing
            with jax.ensure_compile_time_eval():
                stacked = jax.device_get(spec_bank.specs)
                texts = match_formulas(stacked, candidates, props, alphabet_np)
                bank = build_bank(texts, props, alphabet_np)
                banks[spec_bank] = bank, FormulaGraphs(bank)
        return banks[spec_bank]

    def init(params, obs, task_state, key):
        bank, _ = bank_for(task_state)
        return ProgressionCarry(bank.roots[task_state.spec_index], task_state.time)

    def apply(params, obs, task_state, carry: ProgressionCarry, key):
        bank, graphs = bank_for(task_state)
        stepped = step_state(bank, carry.state, task_state.propositions)
        state = jnp.where(task_state.time != carry.time, stepped, carry.state)
        out = network.apply(params, FormulaObs(obs_parts(obs, kinds), state, graphs))
        action = out.pi.mode() if deterministic else out.pi.sample(key)
        return action, ProgressionCarry(state, task_state.time)

    return StatefulPolicy(init, apply)


SPEC = MethodSpec(
    name="ltl2action", title="LTL2Action", make_method=make_method, ppo_config=ppo_config,
    make_policy=make_policy, summarise=summarise,
    options=("formulas", "num_formulas", "seed", "sampler", "encoder", "freeze_encoder",
             "pretrain_steps", "stages", "network", "image_dtype"),
    prepare_training=prepare_training, policy_takes_suites=True,
    pretrain=pretrain_for_world, shipped_encoder=pretrain.shipped_encoder_path,
)
