"""LTL2Action (Vaezipoor et al., ICML'21): policies conditioned on the progressed LTL formula.

The task loop runs a progression source: each episode draws a formula from a bank, and every
label progresses it; +1 and the end of the episode when it progresses to true, -1 and the end
when it progresses to false. The bank holds (`SAMPLERS`) the world's DeepLTL curriculum as
formulas, whose stages advance on the agent's success (LetterWorld, ZoneEnv;
`tasks.curriculum_progression`), or draws of one of the original's samplers (`Until_1_3_1_2`,
`Eventually_1_5_1_4`, `Until_1_2_1_1`, ...; the arm). The network reads the current formula's
syntax tree through a relational GCN (`RGCNEncoder`: 8 rounds of one shared relational
convolution over 4 edge types, hidden 32, readout at the root, 32-d embedding), concatenated with
the observation embedding, into an actor [64, 64, 64] ReLU and a critic [64, 64] Tanh. Dense
layers start as the original's: normal weights with each unit's weight vector of unit norm,
zero biases. The encoder can start from parameters pretrained on the symbol task (the original's
optional LTLBootcamp, `ltl2action_pretrain`; `make_method(pretrain_steps=...)` runs it before
PPO) and stay frozen (`freeze_encoder`). At test time (`make_policy`) the agent progresses the
evaluated formula itself.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, specs
from specrl_jax.baselines.encoders import ImageCNN, check_kinds, obs_parts
from specrl_jax.baselines.ppo.networks import (
    Categorical,
    GaussianHead,
    LetterCNN,
    PolicyOutput,
    unit_columns,
)
from specrl_jax.baselines.ppo.train import PPOConfig, world_config
from specrl_jax.baselines.train_env import TaskTrainEnv
from specrl_jax.specs import CurriculumSampler
from specrl_jax.tasks import StatefulPolicy, TaskEnv
from specrl_jax.tasks.curriculum_progression import CurriculumProgressionSource, stage_formulas
from specrl_jax.tasks.progression import (
    NUM_EDGE_TYPES,
    ProgressionBank,
    ProgressionSource,
    build_bank,
    num_features,
    step_state,
)

#: training formula distribution per world family: "curriculum" (the family's DeepLTL curriculum
#: as formulas, the task distribution the paper calls IND for every baseline) or an original
#: sampler name. The original trains LetterWorld on `Eventually_1_5_1_4` and ZoneEnv on
#: `Until_1_2_1_1`, neither of which holds the paper's IND formulas (docs/fidelity.md,
#: benchmarks/RESULTS.md); the arm has no curriculum and keeps `Until_1_2_1_1`
SAMPLERS = {"letter": "curriculum", "zone": "curriculum", "arm": "Until_1_2_1_1"}
#: the R-GCN's submodule name in the LTL2Action and pretraining networks (what transfers)
ENCODER = "RGCNEncoder_0"  # flax's automatic name, kept so that saved parameters load
#: the DeepLTL curriculum of each family that has one
CURRICULA = {"letter": "deepltl/letter", "zone": "deepltl/zone"}
#: the suites whose formulas the test-time agent recognises unless told otherwise
DEFAULT_SUITES = ("letter/finite/ind", "letter/finite/ood", "letter/infinite/rsp",
                  "letter/infinite/rec", "zone/finite/ind", "zone/finite/ood",
                  "zone/infinite/rsp", "zone/infinite/rec", "zone/infinite/per")


def _dense(features: int) -> nn.Dense:
    return nn.Dense(features, kernel_init=unit_columns)


def relation_kernel_init(key: jax.Array, shape: Sequence[int],
                         dtype: jnp.dtype = jnp.float32) -> jax.Array:
    """DGL 0.4.3 `RelGraphConv`'s basis weights `[R, in, out]`: `xavier_uniform_` with ReLU gain
    under PyTorch's fans for a 3-D tensor (fan_in = in * out, fan_out = R * out), i.e.
    U(-b, b) with b = sqrt(2) sqrt(6 / (in * out + R * out)); 0.0743 for [4, 64, 32]."""
    num_rels, num_in, out = shape
    bound = np.sqrt(2.0) * np.sqrt(6.0 / (num_in * out + num_rels * out))
    return jax.random.uniform(key, shape, dtype, -bound, bound)


def embedding_actor_critic(parts: dict, embedding: jax.Array, num_actions: int,
                           continuous: bool) -> PolicyOutput:
    """LTL2Action's network body, shared with RAD-Embeddings; call it inside a compact module.
    Observation encoders by kind (grid CNN, vector MLP [128, 64] ReLU, image CNN) concatenated
    with the spec `embedding`; actor [64, 64, 64] ReLU then logits (or a Gaussian with Tanh mean
    and state-dependent std); critic [64, 64] Tanh. Dense layers start as the original's."""
    out = []
    if "grid" in parts:
        out.append(LetterCNN()(parts["grid"]))
    if "vector" in parts:
        out.append(nn.relu(_dense(64)(nn.relu(_dense(128)(parts["vector"])))))
    if "image" in parts:
        out.append(ImageCNN()(parts["image"]))
    emb = jnp.concatenate([*out, embedding], axis=-1)
    hidden = emb
    for width in (64, 64, 64):
        hidden = nn.relu(_dense(width)(hidden))
    pi = GaussianHead(num_actions)(hidden) if continuous else Categorical(_dense(num_actions)(hidden))
    value = _dense(1)(nn.tanh(_dense(64)(nn.tanh(_dense(64)(emb)))))[..., 0]
    zeros = jnp.zeros_like(value)
    return PolicyOutput(pi, value, zeros, zeros)


class FormulaObs(NamedTuple):
    """What the LTL2Action network reads (one env; leading batch axes allowed): the world
    observation as encoder parts and the progressed formula's syntax tree (see
    `tasks.progression.ProgressionBank`): `tokens` int16[N] (-1 padding), `parent` int16[N]
    (-1: root or padding), `edge` int8[N]."""

    parts: dict
    tokens: jax.Array
    parent: jax.Array
    edge: jax.Array


class RGCNEncoder(nn.Module):
    """LTL2Action's `RGCN_8x32_ROOT_SHARED` with segment sums.

    `h0 = W_in x` (x one-hot node tokens); `num_layers` times the one shared relational
    convolution `h_i <- tanh(sum_r sum_{j in N_r(i)} W_r [h_j, h0_j] + b)` over the self edge
    (type 0) and the child -> parent edges (types 1-3); the root's hidden, through a Dense layer.
    Node order does not matter: only the parent links and edge types do. The relation weights
    start as DGL 0.4.3's (`relation_kernel_init`), the Dense layers as the original's.
    """

    features: int
    hidden: int = 32
    num_layers: int = 8
    out: int = 32

    @nn.compact
    def __call__(self, tokens: jax.Array, parent: jax.Array, edge: jax.Array) -> jax.Array:
        batch, num_nodes = tokens.shape[:-1], tokens.shape[-1]
        tokens = tokens.reshape(-1, num_nodes).astype(jnp.int32)
        parent = parent.reshape(-1, num_nodes).astype(jnp.int32)
        edge = edge.reshape(-1, num_nodes).astype(jnp.int32)
        num_graphs = tokens.shape[0]
        mask = tokens >= 0
        h0 = _dense(self.hidden)(jax.nn.one_hot(tokens, self.features))  # [G, N, H]
        weight = self.param("relation_kernel", relation_kernel_init,
                            (NUM_EDGE_TYPES, 2 * self.hidden, self.hidden))
        bias = self.param("relation_bias", nn.initializers.zeros_init(), (self.hidden,))
        total = num_graphs * num_nodes
        offsets = (jnp.arange(num_graphs) * num_nodes)[:, None]
        receiver = jnp.where(mask & (parent >= 0), parent + offsets, total).reshape(-1)
        edge_flat = edge.reshape(-1)
        def convolve(_, h):
            x = jnp.concatenate([h, h0], axis=-1).reshape(total, 2 * self.hidden)
            by_type = jnp.einsum("nd,rdo->nro", x, weight)  # [G*N, R, H]
            own = by_type[:, 0]
            message = jnp.take_along_axis(by_type, edge_flat[:, None, None], axis=1)[:, 0]
            incoming = jax.ops.segment_sum(message, receiver, num_segments=total)
            h = jnp.tanh(own + incoming + bias).reshape(num_graphs, num_nodes, self.hidden)
            return jnp.where(mask[..., None], h, 0.0)

        # one shared convolution: a loop keeps the compiled program one layer long
        h = jax.lax.fori_loop(0, self.num_layers, convolve, h0)
        is_root = mask & (parent < 0)
        root = jnp.sum(jnp.where(is_root[..., None], h, 0.0), axis=-2)
        return _dense(self.out)(root).reshape(*batch, self.out)


class LTL2ActionNetwork(nn.Module):
    """Observation encoder (grid CNN, vector MLP [128, 64] ReLU, image CNN) and the R-GCN formula
    embedding, concatenated; actor [64, 64, 64] ReLU then logits (or a Gaussian with Tanh mean
    and state-dependent std); critic [64, 64] Tanh. `freeze_encoder`: no gradient reaches the
    R-GCN (the original's `--freeze-ltl`)."""

    num_actions: int  # discrete actions, or the action dimension when `continuous`
    propositions: tuple[str, ...]
    continuous: bool = False
    freeze_encoder: bool = False

    @nn.compact
    def __call__(self, obs: FormulaObs) -> PolicyOutput:
        formula = RGCNEncoder(num_features(len(self.propositions)), name=ENCODER)(
            obs.tokens, obs.parent, obs.edge)
        if self.freeze_encoder:
            formula = jax.lax.stop_gradient(formula)
        return embedding_actor_critic(obs.parts, formula, self.num_actions, self.continuous)


def network_for(world: Any, freeze_encoder: bool = False) -> LTL2ActionNetwork:
    """The LTL2Action network for a world's action space and propositions."""
    check_kinds(world.obs_kinds)
    space, props = world.action_space, tuple(world.propositions)
    if hasattr(space, "n"):
        return LTL2ActionNetwork(int(space.n), props, freeze_encoder=freeze_encoder)
    return LTL2ActionNetwork(int(space.shape[0]), props, continuous=True,
                             freeze_encoder=freeze_encoder)


def with_encoder(params: Any, encoder: Any) -> Any:
    """`params` of a network with an `ENCODER` submodule, that submodule's parameters replaced
    by `encoder` (an R-GCN's `{"params": ...}`, e.g. `ltl2action_pretrain.encoder_params`).

    Raises:
        ValueError: `encoder` does not have the network's encoder's shapes.
    """
    own, given = params["params"][ENCODER], encoder["params"]
    shapes = jax.tree.map(np.shape, own), jax.tree.map(np.shape, given)
    if shapes[0] != shapes[1]:
        raise ValueError(f"the pretrained encoder's parameters {shapes[1]} do not match the "
                         f"network's R-GCN {shapes[0]} (another number of propositions?)")
    return {**params, "params": {**params["params"], ENCODER: jax.tree.map(jnp.asarray, given)}}


@dataclasses.dataclass(frozen=True)
class LTL2Action:
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
    """`sampler` (default `SAMPLERS[family]`) after checking it names "curriculum" for a family
    with one, or an original sampler.

    Raises:
        ValueError: an unknown family or sampler name, or "curriculum" for the arm.
    """
    if family not in SAMPLERS:
        raise ValueError(f"unknown world family {family!r}; accepted: {', '.join(SAMPLERS)}")
    sampler = SAMPLERS[family] if sampler is None else sampler
    if sampler == "curriculum" and family not in CURRICULA:
        raise ValueError(f"the {family!r} family has no curriculum (families with one: "
                         f"{', '.join(CURRICULA)}); give an original sampler such as "
                         "'Until_1_2_1_1'")
    if sampler != "curriculum":
        specs.ltl2action_sampler(sampler)  # validates the name
    return sampler


def training_formulas(propositions: Sequence[str], family: str = "letter", num_formulas: int = 1024,
                      seed: int = 0, sampler: str | None = None) -> list[list[str]]:
    """The training bank's formula texts by curriculum stage (host, seeded): for `sampler`
    "curriculum" (default: `SAMPLERS[family]`) every task of an enumerated stage and
    `num_formulas` draws of a sampled one; for an original sampler name one list of
    `num_formulas` draws."""
    sampler = check_sampler(family, sampler)
    if num_formulas < 1:
        raise ValueError(f"num_formulas must be >= 1, got {num_formulas}")
    if sampler == "curriculum":
        curriculum = CurriculumSampler(specs.curriculum(CURRICULA[family]), len(propositions))
        return stage_formulas(curriculum, propositions, num_formulas, seed)
    draw = specs.ltl2action_sampler(sampler)
    rng = np.random.default_rng(seed)
    return [[draw(rng, tuple(propositions)) for _ in range(num_formulas)]]


def observe_formula(bank: ProgressionBank, obs_kinds: Mapping[str, str]):
    """`observe(world_obs, task_state) -> FormulaObs` for a progression task loop."""
    kinds = dict(obs_kinds)

    def observe(obs, state):
        return FormulaObs(obs_parts(obs, kinds), *bank.graph(state.task.state))

    return observe


_BANKS: dict[tuple, ProgressionBank] = {}


def make_method(world: Any, params: Any, family: str = "letter",
                formulas: Sequence[str] | None = None,
                num_formulas: int = 1024, seed: int = 0, sampler: str | None = None,
                encoder: Any = None, freeze_encoder: bool = False, pretrain_steps: int = 0,
                stages: Sequence[int] | None = None, network: nn.Module | None = None
                ) -> LTL2Action:
    """LTL2Action on any single-agent world, progressed on the device: the given `formulas`
    (drawn uniformly, or by curriculum stages of sizes `stages`), or `training_formulas(...,
    sampler)` (default `SAMPLERS[family]`; a curriculum's stages advance on the episodes'
    success).

    `encoder`: pretrained R-GCN parameters (or the path of a file saved by
    `ltl2action_pretrain.save_encoder`) the network starts from; `freeze_encoder` keeps the R-GCN
    fixed in training (the original's `--freeze-ltl`); `pretrain_steps` > 0 (without `encoder`)
    has `prepare_training` pretrain it on the symbol task over the same formulas first (the
    original's LTLBootcamp, `--pretrained-gnn`); `network` replaces the LTL2Action network.
    """
    if pretrain_steps < 0:
        raise ValueError(f"pretrain_steps must be >= 0, got {pretrain_steps}")
    if formulas is None:
        by_stage = training_formulas(world.propositions, family, num_formulas, seed, sampler)
        formulas = [f for stage in by_stage for f in stage]
        if check_sampler(family, sampler) == "curriculum":
            stages = [len(stage) for stage in by_stage]
    if isinstance(encoder, (str, os.PathLike)):
        from specrl_jax.baselines import ltl2action_pretrain

        encoder = ltl2action_pretrain.load_encoder(encoder, len(world.propositions))
    network = network_for(world, freeze_encoder) if network is None else network
    alphabet = np.asarray(world.alphabet, bool)
    key = (tuple(formulas), tuple(world.propositions), alphabet.tobytes(), alphabet.shape)
    if key not in _BANKS:  # training, evaluation and loading each build the method once
        _BANKS[key] = build_bank(formulas, world.propositions, alphabet)
    bank = _BANKS[key]
    if stages is None:
        source = ProgressionSource(bank, world.alphabet)
    else:
        curriculum = CurriculumSampler(specs.curriculum(CURRICULA[family]), len(world.propositions))
        source = CurriculumProgressionSource(bank, world.alphabet, curriculum, stages)

    def signals(info):
        reward = info["success"].astype(jnp.float32) - info["violation"].astype(jnp.float32)
        return reward, jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    task = TaskEnv(world, source, observe_formula(bank, world.obs_kinds))
    return LTL2Action(TaskTrainEnv(task, params, signals), network, encoder, pretrain_steps,
                      family, tuple(formulas))


def prepare_training(method: LTL2Action, key: jax.Array, config: PPOConfig,
                     log: Callable[[str], None] = print) -> LTL2Action:
    """Before PPO: with `pretrain_steps` and no encoder yet, pretrain the R-GCN on the symbol
    task over the method's training formulas (one encoder for every seed, as the original
    transfers one) and return the method starting from it."""
    if method.pretrain_steps <= 0 or method.encoder is not None:
        return method
    from specrl_jax.baselines import ltl2action_pretrain

    world = method.env.task.env
    encoder = ltl2action_pretrain.pretrain_encoder(
        np.asarray(world.alphabet), tuple(world.propositions), method.formulas, method.stages,
        method.family, jax.random.fold_in(key, 7), method.pretrain_steps, log)
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
    banks: dict[Any, tuple[ProgressionBank, jax.Array]] = {}

    def bank_for(task_state) -> ProgressionBank:
        spec_bank = task_state.task.bank
        if spec_bank not in banks:
            # host work at trace time: compile and compare concrete arrays, stage nothing
            with jax.ensure_compile_time_eval():
                stacked = jax.device_get(spec_bank.specs)
                texts = match_formulas(stacked, candidates, props, alphabet_np)
                banks[spec_bank] = build_bank(texts, props, alphabet_np)
        return banks[spec_bank]

    def init(params, obs, task_state, key):
        bank = bank_for(task_state)
        return ProgressionCarry(bank.roots[task_state.spec_index], task_state.time)

    def apply(params, obs, task_state, carry: ProgressionCarry, key):
        bank = bank_for(task_state)
        stepped = step_state(bank, carry.state, task_state.propositions)
        state = jnp.where(task_state.time != carry.time, stepped, carry.state)
        out = network.apply(params, FormulaObs(obs_parts(obs, kinds), *bank.graph(state)))
        action = out.pi.mode() if deterministic else out.pi.sample(key)
        return action, ProgressionCarry(state, task_state.time)

    return StatefulPolicy(init, apply)
