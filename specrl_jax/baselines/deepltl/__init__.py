"""DeepLTL (Jackermeier & Abate, ICLR'25): policies conditioned on reach-avoid sequences.

A sequence ((R_1, A_1), ..., (R_n, A_n)) of sets of alphabet symbols is embedded by DeepSets (sum
of symbol embeddings, then an MLP shared by reach and avoid sets) and a GRU read over the reversed
sequence, so the current pair comes last. Training needs no automaton: sequences come from the
world's curriculum through the task loop's sequence source; +1 and the end of the episode when the last pair is reached, -1 and the
end on an avoided symbol. The discrete head has one extra logit, the epsilon action, allowed only
where the current reach is epsilon. At test time (`make_policy`) the automaton state's candidate
sequences are scored by the critic and the best is followed until the automaton state changes.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from specrl_jax import families
from specrl_jax.automata import label_symbol, pairs
from specrl_jax.baselines.encoders import ObsEncoder, check_image_dtype, check_kinds, obs_parts
from specrl_jax.baselines.ppo.networks import (
    MLP,
    DiscreteHead,
    EpsilonGaussianHead,
    PolicyOutput,
    critic,
)
from specrl_jax.baselines.ppo.train import Method, PPOConfig, world_config
from specrl_jax.baselines.scoring import score_chosen
from specrl_jax.baselines.spec import MethodSpec
from specrl_jax.baselines.task_sources import curriculum_of
from specrl_jax.baselines.train_env import TaskTrainEnv, pass_world_reward
from specrl_jax.envs.wrappers import select_tree
from specrl_jax.specs import CurriculumSampler, curriculum, twin_matrix, with_stay
from specrl_jax.tasks import SequenceSource, StatefulPolicy, TaskEnv

PAD, EPSILON, NULL = 0, 1, 2  # token ids before the alphabet symbols


class SequenceObs(NamedTuple):
    """What the DeepLTL network reads (one env; leading batch axes allowed).

    `parts`: the world observation as encoder parts (`encoders.obs_parts`); `reach`/`avoid`
    bool[L, A] symbol sets; `epsilon` bool[L]; pairs `start <= i < end` (int32[]) are the
    remaining sequence; `epsilon_allowed` bool[] (current reach is epsilon and the label is not in
    the next avoid set).
    """

    parts: dict
    reach: jax.Array
    avoid: jax.Array
    epsilon: jax.Array
    start: jax.Array
    end: jax.Array
    epsilon_allowed: jax.Array


class SequenceEncoder(nn.Module):
    """DeepSets over symbol sets + GRU over the reversed remaining sequence (Letter: d 32, MLP
    [32, 32], GRU 64; Zone: d 16, MLP [32, 16], GRU 32)."""

    num_symbols: int
    embed_dim: int = 32
    set_features: tuple[int, ...] = (32, 32)

    @nn.compact
    def __call__(self, obs: SequenceObs) -> jax.Array:
        table = nn.Embed(self.num_symbols + 3, self.embed_dim)
        symbols = table(jnp.arange(3, self.num_symbols + 3))  # [A, d]
        set_net = MLP(self.set_features, "relu")

        def embed_sets(sets: jax.Array, is_epsilon: jax.Array) -> jax.Array:
            summed = sets.astype(jnp.float32) @ symbols  # [..., L, d]
            empty = ~jnp.any(sets, axis=-1, keepdims=True)
            summed = jnp.where(empty, table(jnp.int32(NULL)), summed)
            summed = jnp.where(is_epsilon[..., None], table(jnp.int32(EPSILON)), summed)
            return set_net(summed)

        no_eps = jnp.zeros_like(obs.epsilon)
        pairs = jnp.concatenate([embed_sets(obs.reach, obs.epsilon), embed_sets(obs.avoid, no_eps)], -1)
        gru = nn.GRUCell(features=2 * self.set_features[-1])
        hidden = jnp.zeros((*pairs.shape[:-2], 2 * self.set_features[-1]), jnp.float32)
        positions = jnp.arange(pairs.shape[-2])
        live = (positions >= obs.start[..., None]) & (positions < obs.end[..., None])  # [..., L]
        for i in reversed(range(pairs.shape[-2])):
            updated, _ = gru(hidden, pairs[..., i, :])
            hidden = jnp.where(live[..., i, None], updated, hidden)
        return hidden


class DeepLTLNetwork(nn.Module):
    """Observation encoder, sequence encoder, actor [64, 64, 64] ReLU with `num_actions + 1`
    logits (last = epsilon) or, for continuous actions, a Gaussian plus an epsilon probability;
    critic [64, 64] Tanh."""

    num_actions: int  # discrete actions, or the action dimension when `continuous`
    num_symbols: int
    continuous: bool = False
    embed_dim: int = 32
    set_features: tuple[int, ...] = (32, 32)
    image_dtype: str = "float32"

    @nn.compact
    def __call__(self, obs: SequenceObs) -> PolicyOutput:
        seq = SequenceEncoder(self.num_symbols, self.embed_dim, self.set_features)(obs)
        emb = jnp.concatenate([ObsEncoder(image_dtype=self.image_dtype)(obs.parts), seq], -1)
        hidden = MLP((64, 64, 64), "relu")(emb)
        if self.continuous:
            pi = EpsilonGaussianHead(self.num_actions)(hidden, obs.epsilon_allowed)
        else:
            mask = jnp.concatenate(
                [jnp.ones((*obs.epsilon_allowed.shape, self.num_actions), bool),
                 obs.epsilon_allowed[..., None]], -1)
            pi = DiscreteHead(self.num_actions + 1)(hidden, mask)
        value = critic((64, 64), "tanh")(emb)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(pi, value, zeros, zeros)


def network_for(world: Any, family: str = "letter", image_dtype: str = "float32") -> DeepLTLNetwork:
    """DeepLTL's network for a world (sequence encoder sizes: Letter's, or Zone's elsewhere)."""
    check_kinds(world.obs_kinds)
    space, num_symbols = world.action_space, int(world.alphabet.shape[0])
    sizes = {"embed_dim": 32, "set_features": (32, 32)} if family == "letter" else {
        "embed_dim": 16, "set_features": (32, 16)}
    sizes["image_dtype"] = check_image_dtype(image_dtype)
    if hasattr(space, "n"):
        return DeepLTLNetwork(int(space.n), num_symbols, **sizes)
    return DeepLTLNetwork(int(space.shape[0]), num_symbols, continuous=True, **sizes)


def split_action(network: DeepLTLNetwork):
    """The network's action -> (world action, take_epsilon)."""
    if network.continuous:
        return lambda action: (action[..., :-1], action[..., -1] > 0.5)

    def split(action):
        take_epsilon = action == network.num_actions
        return jnp.where(take_epsilon, 0, action), take_epsilon

    return split


@dataclasses.dataclass(frozen=True)
class DeepLTL(Method):
    """The DeepLTL method for the shared trainer: the task loop with a curriculum sequence source."""

    env: TaskTrainEnv
    network: DeepLTLNetwork

    def init_task_params(self) -> Any:
        return self.env.task.source.init_params()

    def task_metrics(self, task_params: Any) -> dict[str, jax.Array]:
        return {"curriculum_stage": task_params.stage.astype(jnp.float32)}

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return self.env.task.source.sampler.update(
            task_params, stats["_task_id"].reshape(-1), stats["_finished"].reshape(-1),
            stats["_success"].reshape(-1),
        )


def make_method(world: Any, params: Any, family: str | None = None,
                stay_steps: int | None = None, twins_apart: bool = False,
                image_dtype: str = "float32") -> DeepLTL:
    """DeepLTL on any single-agent world, with the curriculum of `family` (letter or zone).

    `stay_steps`: the longest stay of the curriculum's reach-stay tasks, the others scaled with
    it (`specs.with_stay`; None: the original's 30 and 60 steps on Zone). `twins_apart`: no
    avoid set of the curriculum holds a proposition that names the same object as its reach
    (the world's `same_object` pairs, e.g. the grippers-and-arm Arm's `arm_c` / `grippers_c`).
    `image_dtype`: the image CNN's convolutions."""
    family = families.name_of(world, family)
    network = network_for(world, family, image_dtype)
    alphabet = jnp.asarray(world.alphabet, bool)
    name = curriculum_of("deepltl", family)
    if name is None:
        raise ValueError(f"DeepLTL has no curriculum for world family {family!r}")
    tasks = curriculum(name) if stay_steps is None else with_stay(curriculum(name), stay_steps)
    if stay_steps is not None and stay_steps + 1 >= params.max_steps:
        raise ValueError(f"stay_steps={stay_steps}: a stay of {stay_steps} + 1 steps must fit in "
                         f"the world's training episode of {params.max_steps} steps, after "
                         "reaching the zone; take fewer or a longer episode")
    if not isinstance(twins_apart, bool):
        raise TypeError(f"twins_apart must be True or False, got {twins_apart!r}")
    twins = None
    if twins_apart:
        same_object = getattr(world, "same_object", ())
        if not same_object:
            raise ValueError(f"twins_apart: {type(world).__name__} declares no propositions that "
                             "name one object (`same_object`); the grippers-and-arm Arm does")
        twins = twin_matrix(world.propositions, same_object)
    sampler = CurriculumSampler(tasks, world.num_propositions, twins=twins)
    source = SequenceSource(sampler, alphabet)
    kinds = dict(world.obs_kinds)

    def observe(obs, state):
        task = state.task
        current = task.current
        nxt = jnp.minimum(current + 1, task.pairs - 1)
        symbol = label_symbol(alphabet, state.propositions)
        allowed = task.epsilon[current] & ((nxt == current) | ~task.avoid[nxt, symbol])
        return SequenceObs(obs_parts(obs, kinds), task.reach, task.avoid, task.epsilon, current,
                           task.pairs, allowed)

    def signals(info):
        return pass_world_reward(info), jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    task = TaskEnv(world, source, observe)
    return DeepLTL(TaskTrainEnv(task, params, signals, split_action(network)), network)


def summarise(row: dict[str, float]) -> dict[str, float]:
    episodes = max(row["episodes"], 1.0)
    return {**row, "success_rate": row["successes"] / episodes, "violation_rate": row["violations"] / episodes}


def ppo_config(world: str = "letter", **overrides: Any) -> PPOConfig:
    """DeepLTL's settings: LetterWorld 16 x 128, minibatch 256, 8 epochs, gamma 0.94, entropy
    0.01; ZoneEnv 16 x 4096, minibatch 2048, 10 epochs, gamma 0.998, entropy 0.003."""
    return world_config(world, {"update_epochs": 8 if world == "letter" else 10, "loss": "ppo",
                                "vf_coef": 0.5, "gae_lambda": 0.95, "lr": 3e-4}, **overrides)


# ---------------------------------------------------------------------------------------------
# Test time: sequence choice on a compiled automaton


class SeqCarry(NamedTuple):
    q: jax.Array  # int32[], automaton state of the plan
    candidate: jax.Array  # int32[], chosen candidate sequence
    extra_avoid: jax.Array  # bool[A], symbols added to the first avoid set by the value threshold


def threshold_avoid(spec: Any, q: jax.Array, values: jax.Array, valid: jax.Array,
                    best: jax.Array, threshold: float) -> jax.Array:
    """DeepLTL's value threshold at state `q`: the symbols of every other non-self-loop
    out-transition whose best candidate value is more than `threshold` below the chosen one's.

    A transition is identified by its symbols; its best value is the maximum critic value over
    the candidate sequences whose first pair reaches by it (transitions without a candidate are
    left alone, as are epsilon transitions).

    Args:
        spec: one compiled spec; q: int32[] its state.
        values: float32[C] critic value of each candidate; valid: bool[C]; best: int32[] chosen.

    Returns:
        bool[A], the symbols to add to the chosen sequence's first avoid set.
    """
    first = pairs(spec, spec.seq_pair[q, :, 0])  # [C] first pairs
    usable = valid & ~first.epsilon
    reach = first.reach & usable[:, None]  # [C, A]
    best_via = jnp.max(jnp.where(reach, values[:, None], -jnp.inf), axis=0)  # [A]
    self_loop = spec.delta[q] == q
    chosen_reach = jnp.where(first.epsilon[best], False, first.reach[best])
    far_below = values[best] - best_via > threshold
    return jnp.isfinite(best_via) & far_below & ~self_loop & ~chosen_reach


def make_policy(network: nn.Module, alphabet: jax.Array, obs_kinds: dict[str, str],
                deterministic: bool = False, value_threshold: float | None = 0.4,
                deterministic_infinite: bool = False) -> StatefulPolicy:
    """DeepLTL's test-time agent: the candidate sequence of highest critic value, chosen again
    whenever the automaton state changes; stochastic actions by default (the Letter setting).

    `deterministic` sets the action mode on co-safe specs, `deterministic_infinite` on the
    others: the original samples every infinite task, on every world, epsilon action included
    (`eval_test_tasks_infinite.py` hard-codes `deterministic = False`; docs/fidelity.md, DeepLTL
    "Infinite suites"). The mode takes the epsilon action only where its probability passes 0.7.

    `value_threshold` (the original's 0.4): the chosen sequence's first avoid set also gets every
    other non-self-loop transition whose best candidate value is more than this below the chosen
    one's (`threshold_avoid`); None keeps the precomputed avoid sets only. A plan scores the
    valid candidates only, and none when no plan is due (`scoring.score_chosen`).
    """
    alphabet = jnp.asarray(alphabet, bool)
    kinds = dict(obs_kinds)
    split = split_action(network)

    def seq_obs(obs, task_state, c, extra_avoid):
        spec, q = task_state.spec, task_state.q
        symbol = label_symbol(alphabet, task_state.propositions)
        length = spec.seq_length[q, c]
        nxt = jnp.minimum(1, length - 1)
        seq = pairs(spec, spec.seq_pair[q, c])
        avoid = seq.avoid.at[0].set(seq.avoid[0] | extra_avoid)
        allowed = seq.epsilon[0] & ((nxt == 0) | ~avoid[nxt, symbol])
        return SequenceObs(obs_parts(obs, kinds), seq.reach, avoid, seq.epsilon, jnp.int32(0),
                           length, allowed)

    def plan(params, obs, task_state, due):
        """A new `SeqCarry` (meaningless where `due` bool[] is False)."""
        spec, q = task_state.spec, task_state.q
        no_extra = jnp.zeros(alphabet.shape[0], bool)
        valid = spec.seq_valid[q]

        def value(ids):  # mapped over the network: the observation is encoded once
            return jax.vmap(lambda c: network.apply(params, seq_obs(obs, task_state, c, no_extra)).value)(ids)

        values = score_chosen(value, valid & due)
        best = jnp.argmax(jnp.where(valid, values, -jnp.inf)).astype(jnp.int32)
        extra = no_extra if value_threshold is None else threshold_avoid(
            spec, q, values, valid, best, value_threshold)
        return SeqCarry(q, best, extra)

    def init(params, obs, task_state, key):
        return plan(params, obs, task_state, jnp.ones((), bool))

    def apply(params, obs, task_state, carry: SeqCarry, key):
        due = task_state.q != carry.q
        carry = select_tree(due, plan(params, obs, task_state, due), carry)
        pi = network.apply(params, seq_obs(obs, task_state, carry.candidate, carry.extra_avoid)).pi
        spec = task_state.spec
        if deterministic == deterministic_infinite:  # static: one mode for every spec
            output = pi.mode() if deterministic else pi.sample(key)
        else:
            use_mode = jnp.where(spec.is_finite, deterministic, deterministic_infinite)
            output = jnp.where(use_mode, pi.mode(), pi.sample(key))
        action, take_epsilon = split(output)
        slot = spec.pair_epsilon_slot[spec.seq_pair[task_state.q, carry.candidate, 0]]
        return (action, jnp.where(take_epsilon, slot, -1)), carry

    return StatefulPolicy(init, apply)


SPEC = MethodSpec(
    name="deepltl", title="DeepLTL", make_method=make_method, ppo_config=ppo_config,
    make_policy=make_policy, summarise=summarise, deterministic_infinite=lambda family: False,
    options=("stay_steps", "twins_apart", "image_dtype"),
)
