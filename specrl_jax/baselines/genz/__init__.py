"""GenZ-LTL (Guo et al., NeurIPS'25): one reach-avoid subgoal at a time, safety as a hard constraint.

The policy sees no specification encoding: the subgoal is written into the observation by
reducing its proposition axis (`reduce_observation`): on a grid the proposition channels become
one image (reach cells 1.0, avoid cells 0.5, agent 0.2); on LiDAR features the reach and avoid
sets become one max-pooled reading each, on range-bearing features the nearest proposition's
entry each, appended to the robot sensors. It trains
with RCO (`losses.rco_loss`): a reward critic, a reachability-cost critic and a state-dependent
Lagrange multiplier, on the uniform distribution of one-step subgoals (reach one proposition,
avoid 0-3 others) drawn by the task loop's continual sequence source: +1 on reach, then a fresh
subgoal with the return cut there; cost +1 and termination on an avoided proposition (or the
world's own termination, e.g. the walls), -1 otherwise. At test time (`make_policy`) the
automaton state's candidate subgoals are scored by `V_r - lam V_c` and the best is followed until
the state changes or a step budget passes without progress; with no candidate left the episode
is given up (aborted), as the reference's `NoPathsException`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
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
    GaussianHead,
    PolicyOutput,
    critic,
)
from specrl_jax.baselines.ppo.train import Method, PPOConfig, world_config
from specrl_jax.baselines.scoring import score_chosen
from specrl_jax.baselines.spec import MethodSpec
from specrl_jax.baselines.task_sources import curriculum_of
from specrl_jax.baselines.train_env import TaskTrainEnv
from specrl_jax.envs.wrappers import select_tree
from specrl_jax.specs import CurriculumSampler, curriculum
from specrl_jax.tasks import SequenceSource, StatefulPolicy, TaskEnv

REACH, AVOID, AGENT = 1.0, 0.5, 0.2


def _pool(ap: jax.Array, mask: jax.Array) -> jax.Array:
    """The features of the propositions in `mask` bool[P], pooled over the leading proposition
    axis of `ap` float[P, ...]: for range-bearing features `[..., 4]` the entry of the nearest
    one (largest proximity, the last feature), else the elementwise max; zeros for an empty mask."""
    ap = ap.astype(jnp.float32)
    shaped = mask.reshape(mask.shape + (1,) * (ap.ndim - 1))
    if ap.shape[-1] == 4 and ap.ndim >= 3:
        proximity = jnp.where(shaped[..., 0], ap[..., -1], -jnp.inf)
        nearest = jnp.argmax(proximity, axis=0)
        pooled = jnp.take_along_axis(ap, nearest[None, ..., None], axis=0)[0]
    else:
        pooled = jnp.max(jnp.where(shaped, ap, -jnp.inf), axis=0)
    return jnp.where(jnp.any(mask), pooled, 0.0)


def reduce_observation(obs: Mapping[str, jax.Array], obs_kinds: Mapping[str, str],
                       reach: jax.Array, avoid: jax.Array) -> dict[str, jax.Array]:
    """A world observation + subgoal -> the encoder parts GenZ-LTL's policy reads.

    Args:
        obs: one env's observation; `obs["ap"]` has the proposition axis (last for a grid, first
            for LiDAR / range-bearing features).
        obs_kinds: `env.obs_kinds`.
        reach, avoid: bool[P] proposition masks.

    Returns:
        Grid worlds: `{"grid": float32[V, V, 1]}` (the reference's `pre_process_obs_letter`).
        Feature worlds: `{"vector": [other parts, pooled reach, pooled avoid]}` (the reference's
        `pre_process_obs_zones`: robot sensors, max LiDAR of the reach set, of the avoid set).
    """
    if obs_kinds["ap"] == "grid":
        ap = obs["ap"].astype(bool)
        image = jnp.where(jnp.any(ap & reach, -1), REACH,
                          jnp.where(jnp.any(ap & avoid, -1), AVOID, 0.0))
        if obs_kinds.get("ego") == "grid":  # the agent is drawn last, as the reference
            image = jnp.where(obs["ego"][..., 0].astype(bool), AGENT, image)
        parts = obs_parts(obs, obs_kinds, skip=("ap", "ego"))
        parts["grid"] = image[..., None].astype(jnp.float32)
        return parts
    parts = obs_parts(obs, obs_kinds, skip=("ap",))
    pooled = [_pool(obs["ap"], reach).reshape(-1), _pool(obs["ap"], avoid).reshape(-1)]
    parts["vector"] = jnp.concatenate([parts.get("vector", jnp.zeros(0)), *pooled])
    return parts


class GenZNetwork(nn.Module):
    """Observation encoder; actor [64, 64, 64] ReLU (discrete logits, or a Gaussian with Tanh mean
    and state-dependent std); reward critic [64, 64] Softplus with a Softplus output (V_r >= 0);
    cost critic [64, 64] Tanh; multiplier net [64, 64] Softplus, >= 0."""

    num_actions: int = 4  # discrete actions, or the action dimension when `continuous`
    continuous: bool = False
    image_dtype: str = "float32"

    @nn.compact
    def __call__(self, parts: Mapping[str, jax.Array]) -> PolicyOutput:
        emb = ObsEncoder(image_dtype=self.image_dtype)(parts)
        hidden = MLP((64, 64, 64), "relu")(emb)
        pi = GaussianHead(self.num_actions)(hidden) if self.continuous else DiscreteHead(self.num_actions)(hidden)
        value = critic((64, 64), "softplus", final="softplus")(emb)[..., 0]
        cost_value = critic((64, 64), "tanh")(emb)[..., 0]
        multiplier = critic((64, 64), "softplus", final="softplus")(emb)[..., 0]
        return PolicyOutput(pi, value, cost_value, multiplier)


def network_for(world: Any, image_dtype: str = "float32") -> GenZNetwork:
    """The GenZ-LTL network for a world's action space."""
    check_kinds(world.obs_kinds)
    space, image_dtype = world.action_space, check_image_dtype(image_dtype)
    if hasattr(space, "n"):
        return GenZNetwork(int(space.n), image_dtype=image_dtype)
    return GenZNetwork(int(space.shape[0]), continuous=True, image_dtype=image_dtype)


@dataclasses.dataclass(frozen=True)
class GenZ(Method):
    """The GenZ-LTL method for the shared trainer: the task loop with GenZ-LTL's continual
    subgoal source, its reduced observation and its reward / cost signals."""

    env: TaskTrainEnv
    network: GenZNetwork

    def init_task_params(self) -> Any:
        return self.env.task.source.init_params()

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return task_params


def make_method(world: Any, params: Any, family: str | None = None, cost_step: float = -1.0,
                image_dtype: str = "float32") -> GenZ:
    """GenZ-LTL on any single-agent world: subgoals reach 1 proposition and avoid up to 3 others
    (Letter: 2,784 tasks; Zone: 32), drawn from the family record's curriculum (genz/letter,
    genz/zone: the same subgoal distribution). `image_dtype`: the image CNN's convolutions."""
    family = families.name_of(world, family)
    network = network_for(world, image_dtype)
    alphabet = jnp.asarray(world.alphabet, bool)
    name = curriculum_of("genz", family)
    if name is None:
        raise ValueError(f"GenZ-LTL has no curriculum for world family {family!r}")
    sampler = CurriculumSampler(curriculum(name), world.num_propositions)
    source = SequenceSource(sampler, alphabet, continual=True)
    kinds = dict(world.obs_kinds)

    def observe(obs, state):
        reach, avoid = state.task.current_masks(alphabet)
        return reduce_observation(obs, kinds, reach, avoid)

    def signals(info):
        failed = info["violation"] | info["env_terminated"]
        cost = jnp.where(failed, 1.0, cost_step)
        return info["progress"].astype(jnp.float32), cost, info["progress"]

    task = TaskEnv(world, source, observe)
    return GenZ(TaskTrainEnv(task, params, signals), network)


def summarise(row: dict[str, float]) -> dict[str, float]:
    """Per-update rates from summed counts: subgoals reached / violated / timed out."""
    ended = row["reaches"] + row["violations"] + row["timeouts"]
    return {
        **row,
        "success_rate": row["reaches"] / max(ended, 1.0),
        "violation_rate": row["violations"] / max(ended, 1.0),
    }


def ppo_config(world: str = "letter", **overrides: Any) -> PPOConfig:
    """GenZ-LTL's settings (RCO, c_v 1.0, up to 80 epochs with KL stop): LetterWorld 16 x 128,
    minibatch 256, gamma 0.94, entropy 0.01; ZoneEnv 16 x 4096, minibatch 2048, gamma 0.998,
    entropy 0.003, target KL 0.01, lr 3e-4 (the run script's; the saved config says 1e-4)."""
    target_kl = 0.015 if world == "letter" else 0.01
    return world_config(world, {"update_epochs": 80, "loss": "rco", "vf_coef": 1.0,
                                "gae_lambda": 0.95, "lr": 3e-4, "target_kl": target_kl},
                        **overrides)


# ---------------------------------------------------------------------------------------------
# Test time: subgoal choice on a compiled automaton


class PlanCarry(NamedTuple):
    q: jax.Array  # int32[], automaton state the plan was made in (-1: none yet)
    reach: jax.Array  # bool[P], the chosen single-proposition reach
    avoid: jax.Array  # bool[P]
    candidate: jax.Array  # int32[], index of the chosen (sequence, proposition) candidate
    infeasible: jax.Array  # bool[C * P], candidates given up in this automaton state
    steps: jax.Array  # int32[], steps since the plan was made
    stuck: jax.Array  # bool[], no candidate left: the episode is given up


def _first_pairs(spec: Any, q: jax.Array, alphabet: jax.Array
                 ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The first reach-avoid pair of each candidate sequence in state `q` as letter masks:
    `(reach bool[C, P], avoid bool[C, P], usable bool[C])` (see `candidate_masks`)."""
    single = alphabet.sum(-1) == 1  # [A]
    first = pairs(spec, spec.seq_pair[q, :, 0]).epsilon.astype(jnp.int32)  # [C], first non-epsilon pair
    pair = pairs(spec, jnp.take_along_axis(spec.seq_pair[q], first[:, None], axis=1)[:, 0])
    usable = spec.seq_valid[q] & (first < spec.seq_length[q])
    reach_props = jnp.any((pair.reach & single)[..., None] & alphabet, axis=1)  # [C, P]
    avoid_props = jnp.any((pair.avoid & single)[..., None] & alphabet, axis=1)  # [C, P]
    return reach_props, avoid_props, usable


def candidate_masks(spec: Any, q: jax.Array, alphabet: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """GenZ-LTL's candidates in automaton state `q`: the first reach-avoid pair of every path
    the reference's depth-first search finds (the compiled spec's candidate sequences, epsilon
    steps skipped), its reach set split into single letters.

    Returns `(reach bool[C*P, P], avoid bool[C*P, P], valid bool[C*P])`: candidate (c, p) reaches
    letter p while avoiding the letters of pair c's avoid set; a letter inside its own avoid set
    is no candidate. An avoided empty assignment cannot be drawn in the image and is dropped
    (the reference aborts there; docs/fidelity.md).
    """
    return _split_letters(*_first_pairs(spec, q, alphabet))


def _split_letters(reach_props: jax.Array, avoid_props: jax.Array, usable: jax.Array
                   ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """`_first_pairs` -> `candidate_masks`' (reach, avoid, valid)."""
    num_seqs, num_props = reach_props.shape
    reach = jnp.broadcast_to(jnp.eye(num_props, dtype=bool), (num_seqs, num_props, num_props))
    avoid = jnp.broadcast_to(avoid_props[:, None, :], reach.shape)  # [C, P, P]
    valid = usable[:, None] & reach_props & ~avoid_props
    return reach.reshape(-1, num_props), avoid.reshape(-1, num_props), valid.reshape(-1)


def leaves_state(spec: Any, q: jax.Array, num_props: int) -> jax.Array:
    """bool[C*P]: candidate (c, p) reaches from state `q` itself, i.e. sequence c does not begin
    with an epsilon step (then its reach step leaves the epsilon edge's target). A timeout in `q`
    gives up only these, as the reference's `LDBA.mark_unfeasible(states, assignment)` strikes
    the assignment from the transitions leaving those states and never an epsilon edge."""
    here = ~pairs(spec, spec.seq_pair[q, :, 0]).epsilon  # [C]
    return jnp.repeat(here, num_props)


def first_of_kind(avoid_props: jax.Array, allowed: jax.Array) -> jax.Array:
    """bool[C*P]: the `allowed` candidates (c, p) whose pair (letter p, avoid set of c) no earlier
    allowed candidate has. Equal pairs give equal reduced observations, hence equal scores, and
    argmax takes the first: scoring these alone picks the same candidate.

    Args:
        avoid_props: bool[C, P], each sequence's avoid letters (`_first_pairs`).
        allowed: bool[C*P], candidates still open, in `candidate_masks` order.
    """
    num_seqs = avoid_props.shape[0]
    allowed = allowed.reshape(num_seqs, -1)
    same_avoid = jnp.all(avoid_props[:, None] == avoid_props[None], axis=-1)  # [C, C]
    earlier = same_avoid & jnp.tri(num_seqs, k=-1, dtype=bool)  # [c, c'] with c' < c
    taken = jnp.any(earlier[:, :, None] & allowed[None], axis=1)  # [C, P]
    return (allowed & ~taken).reshape(-1)


def epsilon_slot(spec: Any, q: jax.Array, candidate: jax.Array, num_props: int,
                 symbol: jax.Array) -> jax.Array:
    """int32[]: the epsilon slot GenZ-LTL's agent takes now, or -1.

    The chosen candidate (`candidate` = c * P + p, as `candidate_masks`) belongs to sequence c of
    state `q`; when that sequence starts with an epsilon step, the jump is taken as soon as the
    label `symbol` lies outside the avoid set of the pair after it (DeepLTL's epsilon mask, taken
    at once: GenZ-LTL has no epsilon action). For `F G x & G !y` that is on entering x: the jump
    lands in the loop that accepts every step spent in x.
    """
    seq = candidate // num_props
    steps = pairs(spec, spec.seq_pair[q, seq])
    take = (spec.seq_valid[q, seq] & steps.epsilon[0] & (spec.seq_length[q, seq] > 1)
            & ~steps.avoid[1, symbol])
    return jnp.where(take, steps.epsilon_slot[0], -1).astype(jnp.int32)


def make_policy(network: nn.Module, alphabet: jax.Array, obs_kinds: Mapping[str, str],
                deterministic: bool = True, replan_steps: int = 300,
                take_epsilon: bool = True) -> StatefulPolicy:
    """GenZ-LTL's test-time agent as a `StatefulPolicy` for `specrl_jax.eval.evaluate`.

    Plans at the first step and whenever the automaton state changes: the candidate maximising
    `V_r - lam V_c` on its reduced observation, with the multiplier net's own `lam` (the clamp to
    [0.01, 5] belongs to the training loss only, as in the reference). After `replan_steps` steps
    without progress its reach proposition is marked infeasible (every candidate reaching it from
    this state, `leaves_state`) and the next best is taken, unless the last transition was
    accepting (staying is then the goal; the timer restarts). With no candidate left the agent
    gives the episode up (`aborted`, the reference's `NoPathsException`: neither success nor
    violation). Actions are the policy's mode (`deterministic`, the reference's setting) or
    samples.

    Epsilon edges (`F G` formulas): with `take_epsilon` the agent jumps where `epsilon_slot`
    says (inside the goal zone), so the automaton reaches the accepting loop and the timer, which
    never fires on an accepting step, keeps the subgoal. Before the jump a timeout keeps the
    epsilon candidate (its reach step leaves the loop state, not this one, as in the reference's
    marking), so the agent may take as long as it needs to enter x, after a fall-back too. The
    reference's tracker never jumps and its search finds no candidate there (every such episode
    is unreachable, docs/fidelity.md); `take_epsilon=False` never jumps, and an `F G` episode is
    given up at its first timeout.

    A plan scores the distinct open candidates only (`first_of_kind`), and none when no plan is
    due (`scoring.score_chosen`).
    """
    alphabet = jnp.asarray(alphabet, bool)
    obs_kinds = dict(obs_kinds)

    def plan(params, obs, task_state, first, infeasible, due):
        """A new `PlanCarry` from the `_first_pairs` of the state (meaningless where not `due`)."""
        reach, avoid, valid = _split_letters(*first)
        allowed = valid & ~infeasible

        def score_one(r, a):
            out = network.apply(params, reduce_observation(obs, obs_kinds, r, a))
            return out.value - out.multiplier * out.cost_value

        def score(ids):  # mapped over the network: parts no candidate changes are encoded once
            return jax.vmap(score_one)(reach[ids], avoid[ids])

        scores = score_chosen(score, first_of_kind(first[1], allowed) & due)
        best = jnp.argmax(jnp.where(allowed, scores, -jnp.inf))
        return PlanCarry(task_state.q, reach[best], avoid[best], best.astype(jnp.int32), infeasible,
                         jnp.zeros((), jnp.int32), ~jnp.any(allowed))

    def init(params, obs, task_state, key):
        first = _first_pairs(task_state.spec, task_state.q, alphabet)
        num = first[0].size
        return plan(params, obs, task_state, first, jnp.zeros(num, bool), jnp.ones((), bool))

    def apply(params, obs, task_state, carry: PlanCarry, key):
        spec, q = task_state.spec, task_state.q
        moved = q != carry.q
        timed_out = (carry.steps >= replan_steps) & ~moved
        symbol = label_symbol(alphabet, task_state.propositions)
        give_up = timed_out & ~spec.accepting[q, symbol]
        # A timeout gives up the reach proposition itself (every candidate that shares it), as
        # the reference marks the reach assignment infeasible on the transitions leaving the
        # current automaton state; a candidate behind an epsilon edge (`F G x`) keeps it, so an
        # agent that jumps keeps its subgoal and the timer restarts (docs/fidelity.md).
        first = _first_pairs(spec, q, alphabet)
        same_reach = jnp.all(_split_letters(*first)[0] == carry.reach, axis=-1)
        if take_epsilon:  # static; an agent that never jumps cannot follow an epsilon edge
            same_reach = same_reach & leaves_state(spec, q, alphabet.shape[1])
        infeasible = jnp.where(moved, False, carry.infeasible) | (give_up & same_reach)
        due = moved | give_up
        carry = select_tree(due, plan(params, obs, task_state, first, infeasible, due),
                            carry._replace(steps=jnp.where(timed_out, 0, carry.steps)))
        out = network.apply(params, reduce_observation(obs, obs_kinds, carry.reach, carry.avoid))
        action = out.pi.mode() if deterministic else out.pi.sample(key)
        slot = epsilon_slot(spec, q, carry.candidate, alphabet.shape[1], symbol)
        slot = jnp.where(take_epsilon & ~carry.stuck, slot, -1)
        return (action, slot), carry._replace(steps=carry.steps + 1)

    return StatefulPolicy(init, apply, aborted=lambda carry: carry.stuck)


SPEC = MethodSpec(
    name="genz", title="GenZ-LTL", make_method=make_method, ppo_config=ppo_config,
    make_policy=make_policy, summarise=summarise, options=("cost_step", "image_dtype"),
    deterministic=lambda family: True,  # the reference evaluates with mode actions everywhere
    # 80 epochs of 32 minibatches on a 65,536-sample update spend most of an accelerator's time
    # for no gain (docs/fidelity.md: the Letter and Zone PPO shapes)
    accelerator_ppo={"update_epochs": 10},
)
