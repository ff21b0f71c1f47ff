"""DeepLTL (Jackermeier & Abate, ICLR'25): policies conditioned on reach-avoid sequences.

A sequence ((R_1, A_1), ..., (R_n, A_n)) of sets of alphabet symbols is embedded by DeepSets (sum
of symbol embeddings, then an MLP shared by reach and avoid sets) and a GRU read over the reversed
sequence, so the current pair comes last. Training needs no automaton: sequences come from the
LetterWorld curriculum; +1 and the end of the episode when the last pair is reached, -1 and the
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

from specrl_jax.automata import label_symbol, pairs
from specrl_jax.baselines.ppo.networks import MLP, DiscreteHead, LetterCNN, PolicyOutput, critic
from specrl_jax.baselines.ppo.rollout import StepResult
from specrl_jax.baselines.ppo.train import PPOConfig
from specrl_jax.tasks.policy import StatefulPolicy
from specrl_jax.specs import CurriculumSampler, curriculum

PAD, EPSILON, NULL = 0, 1, 2  # token ids before the alphabet symbols


class SequenceObs(NamedTuple):
    """What the DeepLTL network reads (one env; leading batch axes allowed).

    `image` float32[V, V, P + 1] (letters, agent); `reach`/`avoid` bool[L, A] symbol sets;
    `epsilon` bool[L]; pairs `start <= i < end` (int32[]) are the remaining sequence;
    `epsilon_allowed` bool[] (current reach is epsilon and the label is not in the next avoid).
    """

    image: jax.Array
    reach: jax.Array
    avoid: jax.Array
    epsilon: jax.Array
    start: jax.Array
    end: jax.Array
    epsilon_allowed: jax.Array


class SequenceEncoder(nn.Module):
    """DeepSets over symbol sets + GRU over the reversed remaining sequence (Letter: d 32, MLP
    [32, 32], GRU 64)."""

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
    """CNN [16, 32, 64] on the letter image, sequence encoder, actor [64, 64, 64] ReLU with
    `num_actions + 1` logits (last = epsilon), critic [64, 64] Tanh."""

    num_actions: int
    num_symbols: int

    @nn.compact
    def __call__(self, obs: SequenceObs) -> PolicyOutput:
        emb = jnp.concatenate([LetterCNN()(obs.image), SequenceEncoder(self.num_symbols)(obs)], -1)
        mask = jnp.concatenate(
            [jnp.ones((*obs.epsilon_allowed.shape, self.num_actions), bool), obs.epsilon_allowed[..., None]], -1
        )
        pi = DiscreteHead(self.num_actions + 1)(MLP((64, 64, 64), "relu")(emb), mask)
        value = critic((64, 64), "tanh")(emb)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(pi, value, zeros, zeros)


def letter_image(obs: dict[str, jax.Array]) -> jax.Array:
    return jnp.concatenate([obs["ap"], obs["ego"]], axis=-1).astype(jnp.float32)


def symbol_sets(props: jax.Array, alphabet: jax.Array, with_empty: jax.Array | None = None) -> jax.Array:
    """Proposition masks bool[..., P] -> symbol sets bool[..., A]: the symbols making some
    masked proposition true (and the empty symbol where `with_empty`)."""
    hit = jnp.any(props[..., None, :] & alphabet, axis=-1)
    if with_empty is None:
        return hit
    return hit | (with_empty[..., None] & ~jnp.any(alphabet, axis=-1))


class DeepLTLState(NamedTuple):
    world: Any
    label: jax.Array  # bool[P], last label
    reach: jax.Array  # bool[L, A]
    avoid: jax.Array  # bool[L, A]
    epsilon: jax.Array  # bool[L]
    length: jax.Array  # int32[], pairs + repeats to complete
    pairs: jax.Array  # int32[], real pairs
    done_pairs: jax.Array  # int32[], pairs completed
    task_id: jax.Array  # int32[], curriculum task index (-1 sampled)


@dataclasses.dataclass(frozen=True)
class DeepLTLTrainEnv:
    """LetterWorld with DeepLTL's `SequenceWrapper` over a curriculum, auto-resetting."""

    world: Any
    params: Any
    sampler: CurriculumSampler
    num_actions: int = 4

    def observe(self, obs: dict[str, jax.Array], state: DeepLTLState) -> SequenceObs:
        current = jnp.minimum(state.done_pairs, state.pairs - 1)
        nxt = jnp.minimum(current + 1, state.pairs - 1)
        symbol = label_symbol(self.world.alphabet, state.label)
        allowed = state.epsilon[current] & ((nxt == current) | ~state.avoid[nxt, symbol])
        return SequenceObs(letter_image(obs), state.reach, state.avoid, state.epsilon,
                           current, state.pairs, allowed)

    def reset(self, key: jax.Array, task_params: Any) -> tuple[SequenceObs, DeepLTLState]:
        key_world, key_task = jax.random.split(key)
        obs, world = self.world.reset(key_world, self.params)
        seq, task_id = self.sampler.sample(key_task, task_params)
        alphabet = self.world.alphabet
        state = DeepLTLState(
            world, jnp.zeros(self.world.num_propositions, bool),
            symbol_sets(seq.reach, alphabet), symbol_sets(seq.avoid, alphabet, seq.avoid_empty),
            seq.epsilon, seq.length + seq.repeat_last, seq.length, jnp.int32(0), task_id,
        )
        return self.observe(obs, state), state

    def step(self, key: jax.Array, state: DeepLTLState, action: jax.Array, task_params: Any):
        key_step, key_reset = jax.random.split(key)
        take_epsilon = action == self.num_actions
        move = jnp.where(take_epsilon, 0, action)
        obs, world, _, _, truncated, info = self.world.step(key_step, state.world, move, self.params)
        # An epsilon action leaves the world in place but uses up a step of the horizon.
        world = jax.tree.map(lambda a, b: jnp.where(take_epsilon, a, b), state.world, world)
        world = world.replace(time=state.world.time + 1)
        label = jnp.where(take_epsilon, state.label, info["propositions"])
        current = jnp.minimum(state.done_pairs, state.pairs - 1)
        symbol = label_symbol(self.world.alphabet, label)
        violated = ~take_epsilon & state.avoid[current, symbol]
        progressed = jnp.where(take_epsilon, state.epsilon[current],
                               ~state.epsilon[current] & state.reach[current, symbol] & ~violated)
        done_pairs = state.done_pairs + progressed
        succeeded = done_pairs >= state.length
        truncated = truncated & ~violated & ~succeeded
        state = state._replace(world=world, label=label, done_pairs=done_pairs)
        next_obs = self.observe(self._world_obs(world, obs, take_epsilon), state)
        obs_reset, state_reset = self.reset(key_reset, task_params)
        done = violated | succeeded | truncated
        next_obs_, next_state = jax.tree.map(
            lambda a, b: jnp.where(done, a, b), (obs_reset, state_reset), (next_obs, state)
        )
        f32 = lambda x: x.astype(jnp.float32)
        stats = {
            "episodes": f32(done), "successes": f32(succeeded), "violations": f32(violated),
            "_task_id": state.task_id, "_finished": done, "_success": succeeded,
        }
        result = StepResult(
            reward=f32(succeeded) - f32(violated), cost=jnp.zeros((), jnp.float32),
            terminated=violated | succeeded, truncated=truncated, cut=jnp.zeros((), bool),
            final_obs=next_obs, stats=stats,
        )
        return next_obs_, next_state, result

    def _world_obs(self, world: Any, obs: dict[str, jax.Array], take_epsilon: jax.Array):
        return jax.tree.map(lambda a, b: jnp.where(take_epsilon, a, b), self.world.observe(world), obs)


@dataclasses.dataclass(frozen=True)
class DeepLTL:
    """The DeepLTL method for the shared trainer (LetterWorld curriculum)."""

    env: DeepLTLTrainEnv
    network: DeepLTLNetwork

    def init_task_params(self) -> Any:
        return self.env.sampler.init()

    def task_metrics(self, task_params: Any) -> dict[str, jax.Array]:
        return {"curriculum_stage": task_params.stage.astype(jnp.float32)}

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return self.env.sampler.update(
            task_params, stats["_task_id"].reshape(-1), stats["_finished"].reshape(-1),
            stats["_success"].reshape(-1),
        )


def make_method(world: Any, params: Any, curriculum_name: str = "deepltl/letter") -> DeepLTL:
    sampler = CurriculumSampler(curriculum(curriculum_name), world.num_propositions)
    num_actions = world.action_space.n
    env = DeepLTLTrainEnv(world, params, sampler, num_actions)
    return DeepLTL(env, DeepLTLNetwork(num_actions, int(world.alphabet.shape[0])))


def summarise(row: dict[str, float]) -> dict[str, float]:
    episodes = max(row["episodes"], 1.0)
    return {**row, "success_rate": row["successes"] / episodes, "violation_rate": row["violations"] / episodes}


def ppo_config(**overrides: Any) -> PPOConfig:
    """DeepLTL's LetterWorld settings (16 x 128, minibatch 256, 8 epochs, entropy 0.01)."""
    base = {"num_envs": 16, "num_steps": 128, "num_minibatches": 8, "update_epochs": 8, "loss": "ppo",
                "vf_coef": 0.5, "ent_coef": 0.01, "gamma": 0.94, "gae_lambda": 0.95, "lr": 3e-4}
    return PPOConfig(**{**base, **overrides})


# ---------------------------------------------------------------------------------------------
# Test time: sequence choice on a compiled automaton


class SeqCarry(NamedTuple):
    q: jax.Array  # int32[], automaton state of the plan
    candidate: jax.Array  # int32[], chosen candidate sequence


def make_policy(network: nn.Module, alphabet: jax.Array, num_actions: int = 4,
                deterministic: bool = False) -> StatefulPolicy:
    """DeepLTL's test-time agent: the candidate sequence of highest critic value, chosen again
    whenever the automaton state changes; stochastic actions by default (the Letter setting)."""
    alphabet = jnp.asarray(alphabet, bool)

    def seq_obs(obs, task_state, c):
        spec, q = task_state.spec, task_state.q
        symbol = label_symbol(alphabet, task_state.propositions)
        length = spec.seq_length[q, c]
        nxt = jnp.minimum(1, length - 1)
        seq = pairs(spec, spec.seq_pair[q, c])
        allowed = seq.epsilon[0] & ((nxt == 0) | ~seq.avoid[nxt, symbol])
        return SequenceObs(letter_image(obs), seq.reach, seq.avoid, seq.epsilon, jnp.int32(0),
                           length, allowed)

    def plan(params, obs, task_state):
        num = task_state.spec.seq_valid.shape[1]
        cands = jax.vmap(lambda c: seq_obs(obs, task_state, c))(jnp.arange(num))
        values = network.apply(params, cands).value
        valid = task_state.spec.seq_valid[task_state.q]
        return SeqCarry(task_state.q, jnp.argmax(jnp.where(valid, values, -jnp.inf)).astype(jnp.int32))

    def init(params, obs, task_state, key):
        return plan(params, obs, task_state)

    def apply(params, obs, task_state, carry: SeqCarry, key):
        carry = jax.lax.cond(task_state.q != carry.q, lambda: plan(params, obs, task_state), lambda: carry)
        pi = network.apply(params, seq_obs(obs, task_state, carry.candidate)).pi
        action = pi.mode() if deterministic else pi.sample(key)
        take_epsilon = action == num_actions
        spec = task_state.spec
        slot = spec.pair_epsilon_slot[spec.seq_pair[task_state.q, carry.candidate, 0]]
        return (jnp.where(take_epsilon, 0, action), jnp.where(take_epsilon, slot, -1)), carry

    return StatefulPolicy(init, apply)
