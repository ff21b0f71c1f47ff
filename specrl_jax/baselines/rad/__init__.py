"""RAD-Embeddings (Yalcinkaya et al., NeurIPS'24): policies conditioned on a pretrained, frozen
embedding of the task's conjunction of DFAs.

Training (the family record's task source): LetterWorld and ZoneEnv train by default on a `CurriculumDFASource` over
the world's DeepLTL curriculum as DFAs ("curriculum": each stage's tasks as minimal DFAs, stages
advancing on the agent's success, reach-stay tasks left out), the distribution with which the
paper's PointLTL0 figure reproduces (docs/fidelity.md); "rad" is the original's: a
`tasks.dfa_source.DFASource` over a bank of RAD conjunctions (`automata.rad_sampler`, the
`CompositionalReachAvoidDerived` sampler over the world's alphabet), the arm's default. +1 and
the end of the episode when every DFA accepts, -1 and the end when one can no longer accept.
Every observation carries the 32-d embedding of the advanced, minimised conjunction by the
pretrained GATv2 encoder (`rad_encoder`, parameters shipped in
`baselines/data/rad_encoder_<family>.msgpack`, made by `specrl-jax pretrain --method rad`), frozen
(the original's `--freeze`), so PPO never backpropagates into it. Being frozen, the encoder runs once per reachable state of the bank when the method is
built (`rad_table`), and the task loop reads the embedding off that table. The network is
LTL2Action's: observation encoder (grid CNN, vector MLP [128, 64] ReLU, image CNN) concatenated
with the embedding, actor [64, 64, 64] ReLU, critic [64, 64] Tanh, dense layers with unit-norm
weight vectors and zero biases.

Test time (`make_policy`): the evaluated specs are the project's compiled automata; each
co-safe spec becomes its minimal DFA of good prefixes (`rad_sampler.bank_of_specs`) and the
agent reads the DFA state off the task loop's automaton state through the minimisation's state
map. Specs that are not co-safe have no DFA: `usable_suites` leaves infinite suites out, and a
policy given such a spec raises ValueError.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import families, specs
from specrl_jax.automata import rad_sampler
from specrl_jax.automata.rad_sampler import DFABank
from specrl_jax.baselines.encoders import check_image_dtype, check_kinds, obs_parts
from specrl_jax.baselines.heads import embedding_actor_critic
from specrl_jax.baselines.ppo.networks import PolicyOutput
from specrl_jax.baselines.ppo.train import Method, PPOConfig, world_config
from specrl_jax.baselines.rad import disk as rad_disk
from specrl_jax.baselines.rad import pretrain as rad_pretrain
from specrl_jax.baselines.rad import table as rad_table
from specrl_jax.baselines.rad.encoder import (
    GraphBank,
    RADEncoder,
    build_graphs,
    graph_of,
    packing_allowance,
)
from specrl_jax.baselines.spec import MethodSpec
from specrl_jax.baselines.task_sources import curriculum_of, families_with_curriculum, task_source
from specrl_jax.baselines.train_env import TaskTrainEnv, pass_world_reward
from specrl_jax.specs import CurriculumSampler
from specrl_jax.tasks import TaskEnv
from specrl_jax.tasks.dfa_source import CurriculumDFASource, DFASource

DEFAULT_BANK_SIZE = 4096
#: draws of each sampled curriculum stage (before reach-stay draws are left out)
CURRICULUM_DRAWS = 1024

class RADObs(NamedTuple):
    """What the RAD policy reads (one env; leading batch axes allowed): the world observation as
    encoder parts and the frozen embedding float32[32] of the task's conjunction of DFAs."""

    parts: dict
    embedding: jax.Array


class RADNetwork(nn.Module):
    """Observation encoder and the frozen DFA embedding, concatenated; actor [64, 64, 64] ReLU
    then logits (or a Gaussian with Tanh mean and state-dependent std); critic [64, 64] Tanh.
    `encoder` names the frozen encoder's parameters (a world family or a file path)."""

    num_actions: int  # discrete actions, or the action dimension when `continuous`
    encoder: str
    continuous: bool = False
    image_dtype: str = "float32"

    @nn.compact
    def __call__(self, obs: RADObs) -> PolicyOutput:
        return embedding_actor_critic(obs.parts, obs.embedding, self.num_actions, self.continuous,
                                      self.image_dtype)


def network_for(world: Any, encoder: str = "letter", image_dtype: str = "float32") -> RADNetwork:
    """The RAD network for a world's action space, reading the frozen encoder `encoder`."""
    check_kinds(world.obs_kinds)
    space, image_dtype = world.action_space, check_image_dtype(image_dtype)
    if hasattr(space, "n"):
        return RADNetwork(int(space.n), encoder, image_dtype=image_dtype)
    return RADNetwork(int(space.shape[0]), encoder, continuous=True, image_dtype=image_dtype)


def frozen_encoder(encoder_params: Any, num_layers: int = 8,
                   packing: tuple[float, ...] | None = None) -> RADEncoder:
    """The encoder of `encoder_params` (widths read off them) with `num_layers` rounds of the
    shared layer (the original's 8), encoding batches packed by `packing` if given."""
    p = encoder_params["params"]
    return RADEncoder(hidden=int(np.shape(p["embed"]["kernel"])[-1]), num_layers=num_layers,
                      out=int(np.shape(p["readout"]["kernel"])[-1]), packing=packing)


def embedder(encoder_params: Any, graphs: GraphBank, bank: DFABank, num_layers: int = 8
             ) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """`embed(index, q) -> float32[32]`: the frozen embedding of conjunction `index` of `bank`
    at states `q` int32[N] (one task), by the encoder of `num_layers` rounds."""
    encoder = frozen_encoder(encoder_params, num_layers)

    def embed(index, q):
        graph = graph_of(graphs, bank, index, q)
        return jax.lax.stop_gradient(encoder.apply(encoder_params, graph))

    return embed


def bank_embedder(encoder_params: Any, graphs: GraphBank, bank: DFABank, num_layers: int = 8,
                  max_table_rows: int = rad_table.MAX_TABLE_ROWS
                  ) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """`embedder`'s `embed`, read from a table of every reachable state tuple of `bank` encoded
    once (`rad_table`, the encoder batched and packed; read from the disk cache, `rad.disk`), so
    no step runs the encoder. Where the table would exceed `max_table_rows` rows, `embed` itself
    with a warning (0: always).
    """
    embed = embedder(encoder_params, graphs, bank, num_layers)
    if max_table_rows <= 0:
        return embed
    encoder = frozen_encoder(encoder_params, num_layers, packing_allowance(graphs, bank))

    def encode(index, q):  # index int32[B], q int32[B, N]
        graph = jax.vmap(graph_of, in_axes=(None, None, 0, 0))(graphs, bank, index, q)
        return encoder.apply(encoder_params, graph)

    try:
        table = rad_disk.embedding_table(encoder_params, bank, num_layers, max_table_rows,
                                         lambda: rad_table.build_table(bank, encode, max_table_rows))
    except ValueError as err:
        warnings.warn(f"RAD-Embeddings: {err}; running the encoder every step instead",
                      stacklevel=2)
        return embed
    return functools.partial(rad_table.lookup, table)


@dataclasses.dataclass(frozen=True)
class RAD(Method):
    """The RAD method for the shared trainer: the task loop over a DFA source."""

    env: TaskTrainEnv
    network: RADNetwork

    def init_task_params(self) -> Any:
        """The source's params: the curriculum state on a curriculum, else None."""
        return self.env.task.source.init_params()

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return self.env.task.source.update_params(task_params, stats)

    def task_metrics(self, task_params: Any) -> dict[str, jax.Array]:
        if task_params is None:
            return {}
        return {"curriculum_stage": task_params.stage.astype(jnp.float32)}


_BANKS: dict[tuple, tuple] = {}


def training_bank(alphabet: np.ndarray, bank_size: int = DEFAULT_BANK_SIZE, seed: int = 0
                  ) -> tuple[DFABank, GraphBank]:
    """A bank of `bank_size` RAD conjunctions over `alphabet` and its graphs (built once per
    process and alphabet: training, evaluation and loading each build the method)."""
    alphabet = np.asarray(alphabet, bool)
    key = (alphabet.tobytes(), alphabet.shape, bank_size, seed)
    if key not in _BANKS:
        bank = rad_sampler.sample_bank(bank_size, alphabet, seed, rad_pretrain.MAX_GRAPH_NODES)
        _BANKS[key] = (bank, build_graphs(bank))
    return _BANKS[key]


def check_sampler(family: str, sampler: str | None) -> str:
    """`sampler` (default: the family record's task source, "curriculum" where it is a
    curriculum) after checking it is "rad", or "curriculum" for a family with one.

    Raises:
        ValueError: an unknown family or sampler, or "curriculum" for a family without one.
    """
    source = task_source("rad", family)
    if source is None:
        known = [f for f in families.list_families() if task_source("rad", f)]
        raise ValueError(f"RAD: no sampler for world family {family!r} (families: "
                         f"{', '.join(known)})")
    if sampler is None:
        sampler = "curriculum" if curriculum_of("rad", family) else source
    if sampler not in ("rad", "curriculum"):
        raise ValueError(f"unknown RAD sampler {sampler!r}; accepted: 'rad', 'curriculum'")
    if sampler == "curriculum" and curriculum_of("rad", family) is None:
        raise ValueError(f"the {family!r} family has no curriculum (families with one: "
                         f"{', '.join(families_with_curriculum('rad'))})")
    return sampler


def curriculum_bank(propositions: Sequence[str], alphabet: np.ndarray, family: str,
                    per_stage: int = CURRICULUM_DRAWS, seed: int = 0
                    ) -> tuple[CurriculumSampler, list[int], DFABank, GraphBank]:
    """`family`'s DeepLTL curriculum as DFAs (`dfa_source.curriculum_dfas`, `per_stage` draws of
    a sampled stage): its sampler, the rows per stage, the bank and its graphs (built once per
    process, as `training_bank`; the DFAs read from the disk cache, `rad.disk`)."""
    alphabet = np.asarray(alphabet, bool)
    key = ("curriculum", family, tuple(propositions), alphabet.tobytes(), alphabet.shape,
           per_stage, seed)
    if key not in _BANKS:
        sampler = CurriculumSampler(specs.curriculum(curriculum_of("rad", family)), len(propositions))
        tasks = rad_disk.curriculum_dfas(sampler, propositions, alphabet, per_stage, seed)
        _BANKS[key] = (sampler, tasks.stage_sizes, tasks.bank, build_graphs(tasks.bank))
    return _BANKS[key]


#: the embedders of training banks under shipped encoders, built once per process (a table
#: takes seconds on a GPU, minutes on a CPU; training, evaluation and loading each build the method)
_EMBEDDERS: dict[tuple, Callable[[jax.Array, jax.Array], jax.Array]] = {}


def make_method(world: Any, params: Any, family: str | None = None, bank: DFABank | None = None,
                bank_size: int = DEFAULT_BANK_SIZE, seed: int = 0,
                encoder: str | None = None, encoder_params: Any = None,
                encoder_layers: int = 8, max_table_rows: int = rad_table.MAX_TABLE_ROWS,
                sampler: str | None = None, per_stage: int = CURRICULUM_DRAWS,
                image_dtype: str = "float32") -> RAD:
    """RAD on any single-agent world: the training tasks are `bank` (drawn uniformly) if given,
    else by `sampler` (default: the family's task source) a bank of `bank_size` RAD conjunctions ("rad")
    or `family`'s curriculum as DFAs, `per_stage` draws of a sampled stage ("curriculum"),
    embedded by the frozen encoder `encoder` (default: the family's `formula_encoder`; or
    `encoder_params` of `encoder_layers` rounds). The embeddings of the bank's reachable states
    are encoded once into a table, or every step where it would exceed `max_table_rows` rows
    (`bank_embedder`). `image_dtype`: the image CNN's convolutions."""
    family = families.name_of(world, family)
    alphabet = np.asarray(world.alphabet, bool)
    if encoder is None:  # the grippers-only arm's alphabet is ZoneEnv's: it reads the Zone encoder
        encoder = families.encoder_name(family, alphabet, per_symbol=True)
    shared = bank is None and encoder_params is None
    sampler = check_sampler(family, sampler)
    cache_key = (alphabet.tobytes(), alphabet.shape, bank_size, seed, encoder, encoder_layers,
                 max_table_rows, sampler, per_stage, family, tuple(world.propositions))
    if encoder_params is None:
        encoder_params = rad_pretrain.load_encoder(encoder, alphabet.shape[0])
    curriculum = None
    if bank is not None:
        graphs = build_graphs(bank)
    elif sampler == "curriculum":
        curriculum, stage_sizes, bank, graphs = curriculum_bank(world.propositions, alphabet,
                                                                family, per_stage, seed)
    else:
        bank, graphs = training_bank(alphabet, bank_size, seed)
    if shared and cache_key in _EMBEDDERS:
        embed = _EMBEDDERS[cache_key]
    else:
        embed = bank_embedder(encoder_params, graphs, bank, encoder_layers, max_table_rows)
        if shared:
            _EMBEDDERS[cache_key] = embed
    kinds = dict(world.obs_kinds)

    def observe(obs, state):
        return RADObs(obs_parts(obs, kinds), embed(state.task.index, state.task.q))

    def signals(info):
        return pass_world_reward(info), jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    if curriculum is None:
        source = DFASource(bank, world.alphabet)
    else:
        source = CurriculumDFASource(bank, world.alphabet, curriculum, stage_sizes)
    task = TaskEnv(world, source, observe)
    return RAD(TaskTrainEnv(task, params, signals), network_for(world, encoder, image_dtype))


def pretrain_for_world(world: Any, family: str, key: jax.Array, steps: int,
                       log: Callable[[str], None] = print, bank_size: int = 8192, seed: int = 0,
                       **ppo_shape: Any) -> Any:
    """The encoder pretrained on the symbol task over `world`'s alphabet (`rad.pretrain`)."""
    return rad_pretrain.pretrain_encoder(np.asarray(world.alphabet), tuple(world.propositions),
                                         family, key, steps, bank_size, seed, log, **ppo_shape)


def summarise(row: dict[str, float]) -> dict[str, float]:
    episodes = max(row["episodes"], 1.0)
    return {**row, "success_rate": row["successes"] / episodes,
            "violation_rate": row["violations"] / episodes}


def ppo_config(world: str = "letter", **overrides: Any) -> PPOConfig:
    """RAD's downstream settings (the original's scripts, LTL2Action's PPO): LetterWorld 16 x
    128, minibatch 256, 4 epochs, gamma 0.94, entropy 0.01; ZoneEnv 16 x 4096, minibatch 2048,
    10 epochs, gamma 0.998, entropy 0.003; lr 3e-4, GAE 0.95, clip 0.2. The arm (no original
    setting) takes ZoneEnv's with gamma 0.99 and 16 x 1024."""
    return world_config(world, {"update_epochs": 4 if world == "letter" else 10, "loss": "ppo",
                                "vf_coef": 0.5, "gae_lambda": 0.95, "lr": 3e-4}, **overrides)


def usable_suites(suites: Sequence[str], log: Callable[[str], None] = print) -> list[str]:
    """The suites whose specs are co-safe (finite horizon): RAD's DFAs decide those only."""
    keep = [s for s in suites if specs.suite_info(s).horizon == "finite"]
    if len(keep) < len(suites):
        log(f"RAD-Embeddings: skipping {sorted(set(suites) - set(keep))} (not co-safe: no DFA)")
    return keep


def make_policy(network: RADNetwork, alphabet: jax.Array, obs_kinds: Mapping[str, str],
                deterministic: bool = False, encoder_params: Any = None,
                encoder_layers: int = 8, max_table_rows: int = rad_table.MAX_TABLE_ROWS
                ) -> Callable[..., jax.Array]:
    """RAD's test-time agent: `policy(params, obs, task_state, key) -> action` for
    `specrl_jax.eval.evaluate`. The evaluated bank of compiled specs becomes a bank of DFAs once
    (at trace time), and the embedding of each of their states a table row (`bank_embedder`,
    per step above `max_table_rows` rows); each step reads the DFA at the state the task loop's
    automaton state maps to. Actions are sampled, or the mode where `deterministic`. The frozen
    encoder is `network.encoder`'s unless `encoder_params` (of `encoder_layers` rounds) are given.

    Raises:
        ValueError (when traced): an evaluated spec is not co-safe.
    """
    kinds = dict(obs_kinds)
    if encoder_params is None:
        encoder_params = rad_pretrain.load_encoder(network.encoder, int(np.shape(alphabet)[0]))
    banks: dict[Any, tuple[Callable, jax.Array]] = {}

    def bank_for(task_state):
        spec_bank = task_state.task.bank
        if spec_bank not in banks:
            with jax.ensure_compile_time_eval():
                bank, state_map = rad_sampler.bank_of_specs(spec_bank.specs)
                banks[spec_bank] = (bank_embedder(encoder_params, build_graphs(bank), bank,
                                                  encoder_layers, max_table_rows),
                                    jnp.asarray(state_map))
        return banks[spec_bank]

    def policy(params, obs, task_state, key):
        embed, state_map = bank_for(task_state)
        index = task_state.spec_index
        q = jnp.maximum(state_map[index, task_state.q], 0)[None]  # reached states map to >= 0
        out = network.apply(params, RADObs(obs_parts(obs, kinds), embed(index, q)))
        return out.pi.mode() if deterministic else out.pi.sample(key)

    return policy


SPEC = MethodSpec(
    name="rad", title="RAD-Embeddings", make_method=make_method, ppo_config=ppo_config,
    make_policy=make_policy, summarise=summarise,
    options=("bank", "bank_size", "seed", "encoder", "encoder_params", "encoder_layers",
             "max_table_rows", "sampler", "per_stage", "image_dtype"),
    usable_suites=usable_suites, pretrain=pretrain_for_world,
    shipped_encoder=rad_pretrain.encoder_path, encoder_per_symbol=True,
)
