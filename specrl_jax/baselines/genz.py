"""GenZ-LTL (Guo et al., NeurIPS'25): one reach-avoid subgoal at a time, safety as a hard constraint.

The policy sees no specification encoding: the subgoal is written into the observation, the
proposition channels reduced to one image (reach cells 1.0, avoid cells 0.5, agent 0.2). It
trains with RCO (`losses.rco_loss`): a reward critic, a reachability-cost critic and a
state-dependent Lagrange multiplier, on the uniform distribution of one-step subgoals (reach one
letter, avoid 0-3 others); +1 on reach, then a fresh subgoal with the return cut there; cost +1
and termination on an avoided letter, -1 otherwise. At test time (`make_policy`) the automaton
state's candidate subgoals are scored by `V_r - lam V_c` and the best is followed until the
state changes or a step budget passes without progress; with no candidate left the episode is
given up (aborted), as the reference's `NoPathsException`.
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
from specrl_jax.specs import genz_tasks, sample_genz_subgoal

REACH, AVOID, AGENT = 1.0, 0.5, 0.2


def reduce_observation(obs: dict[str, jax.Array], reach: jax.Array, avoid: jax.Array) -> jax.Array:
    """LetterWorld obs + subgoal -> float32[V, V, 1] (GenZ-LTL's `pre_process_obs_letter`).

    Args:
        obs: `ap` uint8[V, V, P] letter channels, `ego` uint8[V, V, 1] agent channel.
        reach, avoid: bool[P] proposition masks.
    """
    ap = obs["ap"].astype(bool)
    reach_map = jnp.any(ap & reach, axis=-1)
    avoid_map = jnp.any(ap & avoid, axis=-1)
    image = jnp.where(reach_map, REACH, jnp.where(avoid_map, AVOID, 0.0))
    image = jnp.where(obs["ego"][..., 0].astype(bool), AGENT, image)  # drawn last, as the reference
    return image[..., None].astype(jnp.float32)


class GenZNetwork(nn.Module):
    """CNN on the reduced image; actor [64, 64, 64] ReLU; reward critic [64, 64] Softplus with a
    Softplus output (V_r >= 0); cost critic [64, 64] Tanh; multiplier net [64, 64] Softplus, >= 0."""

    num_actions: int = 4

    @nn.compact
    def __call__(self, image: jax.Array) -> PolicyOutput:
        emb = LetterCNN()(image)
        pi = DiscreteHead(self.num_actions)(MLP((64, 64, 64), "relu")(emb))
        value = critic((64, 64), "softplus", final="softplus")(emb)[..., 0]
        cost_value = critic((64, 64), "tanh")(emb)[..., 0]
        multiplier = critic((64, 64), "softplus", final="softplus")(emb)[..., 0]
        return PolicyOutput(pi, value, cost_value, multiplier)


class GenZState(NamedTuple):
    world: Any
    reach: jax.Array  # bool[P]
    avoid: jax.Array  # bool[P]


@dataclasses.dataclass(frozen=True)
class GenZTrainEnv:
    """LetterWorld with GenZ-LTL's subgoal wrapper (`SequenceSafetyWrapper`), auto-resetting."""

    world: Any
    params: Any
    max_avoid: int = 3
    cost_step: float = -1.0

    def _subgoal(self, key: jax.Array, current: jax.Array) -> tuple[jax.Array, jax.Array]:
        tasks = genz_tasks(self.world.num_propositions, self.max_avoid)
        sequence, _ = sample_genz_subgoal(key, tasks, current)
        return sequence.reach[0], sequence.avoid[0]

    def reset(self, key: jax.Array, task_params: Any = None) -> tuple[jax.Array, GenZState]:
        key_world, key_goal = jax.random.split(key)
        obs, world = self.world.reset(key_world, self.params)
        reach, avoid = self._subgoal(key_goal, jnp.zeros(self.world.num_propositions, bool))
        return reduce_observation(obs, reach, avoid), GenZState(world, reach, avoid)

    def step(self, key: jax.Array, state: GenZState, action: jax.Array, task_params: Any = None):
        key_step, key_goal, key_reset = jax.random.split(key, 3)
        obs, world, _, _, truncated, info = self.world.step(key_step, state.world, action, self.params)
        props = info["propositions"]
        violated = jnp.any(props & state.avoid)
        reached = jnp.any(props & state.reach) & ~violated
        truncated = truncated & ~violated
        final_obs = reduce_observation(obs, state.reach, state.avoid)
        reach, avoid = self._subgoal(key_goal, props)
        reach = jnp.where(reached, reach, state.reach)
        avoid = jnp.where(reached, avoid, state.avoid)
        next_obs, next_state = reduce_observation(obs, reach, avoid), GenZState(world, reach, avoid)
        obs_reset, state_reset = self.reset(key_reset)
        done = violated | truncated
        next_obs, next_state = jax.tree.map(
            lambda a, b: jnp.where(done, a, b), (obs_reset, state_reset), (next_obs, next_state)
        )
        f32 = lambda x: x.astype(jnp.float32)
        stats = {
            "episodes": f32(done),
            "reaches": f32(reached),
            "violations": f32(violated),
            "timeouts": f32(truncated),
        }
        result = StepResult(
            reward=f32(reached),
            cost=jnp.where(violated, 1.0, self.cost_step),
            terminated=violated,
            truncated=truncated,
            cut=reached,
            final_obs=final_obs,
            stats=stats,
        )
        return next_obs, next_state, result


@dataclasses.dataclass(frozen=True)
class GenZ:
    """The GenZ-LTL method for the shared trainer (LetterWorld)."""

    env: GenZTrainEnv
    network: GenZNetwork

    def init_task_params(self) -> Any:
        return None

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return task_params


def make_method(world: Any, params: Any) -> GenZ:
    return GenZ(GenZTrainEnv(world, params), GenZNetwork(world.action_space.n))


def summarise(row: dict[str, float]) -> dict[str, float]:
    """Per-update rates from summed counts: subgoals reached / violated / timed out."""
    ended = row["reaches"] + row["violations"] + row["timeouts"]
    return {
        **row,
        "success_rate": row["reaches"] / max(ended, 1.0),
        "violation_rate": row["violations"] / max(ended, 1.0),
    }


def ppo_config(**overrides: Any) -> PPOConfig:
    """GenZ-LTL's LetterWorld settings (RCO, c_v 1.0, up to 80 epochs with KL stop 0.015)."""
    base = {
        "num_envs": 16, "num_steps": 128, "num_minibatches": 8, "update_epochs": 80, "target_kl": 0.015,
        "loss": "rco", "vf_coef": 1.0, "ent_coef": 0.01, "gamma": 0.94, "gae_lambda": 0.95, "lr": 3e-4,
    }
    return PPOConfig(**{**base, **overrides})


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


def candidate_masks(spec: Any, q: jax.Array, alphabet: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """GenZ-LTL's candidates in automaton state `q`: the first reach-avoid pair of every path
    the reference's depth-first search finds (the compiled spec's candidate sequences, epsilon
    steps skipped), its reach set split into single letters.

    Returns `(reach bool[C*P, P], avoid bool[C*P, P], valid bool[C*P])`: candidate (c, p) reaches
    letter p while avoiding the letters of pair c's avoid set; a letter inside its own avoid set
    is no candidate. An avoided empty assignment cannot be drawn in the image and is dropped
    (the reference aborts there; docs/fidelity.md).
    """
    num_props = alphabet.shape[1]
    single = alphabet.sum(-1) == 1  # [A]
    first = pairs(spec, spec.seq_pair[q, :, 0]).epsilon.astype(jnp.int32)  # [C], first non-epsilon pair
    pair = pairs(spec, jnp.take_along_axis(spec.seq_pair[q], first[:, None], axis=1)[:, 0])
    reach_sym, avoid_sym = pair.reach & single, pair.avoid & single
    usable = spec.seq_valid[q] & (first < spec.seq_length[q])
    reach_props = jnp.any(reach_sym[..., None] & alphabet, axis=1)  # [C, P]
    avoid_props = jnp.any(avoid_sym[..., None] & alphabet, axis=1)  # [C, P]
    eye = jnp.eye(num_props, dtype=bool)
    reach = jnp.broadcast_to(eye, (reach_props.shape[0], num_props, num_props))  # [C, P, P]
    avoid = jnp.broadcast_to(avoid_props[:, None, :], reach.shape)
    valid = usable[:, None] & reach_props & ~avoid_props
    return reach.reshape(-1, num_props), avoid.reshape(-1, num_props), valid.reshape(-1)


def make_policy(network: nn.Module, alphabet: jax.Array, deterministic: bool = True,
                replan_steps: int = 300) -> StatefulPolicy:
    """GenZ-LTL's test-time agent as a `StatefulPolicy` for `specrl_jax.eval.evaluate`.

    Plans at the first step and whenever the automaton state changes: the candidate maximising
    `V_r - lam V_c` on its reduced observation, with the multiplier net's own `lam` (the clamp to
    [0.01, 5] belongs to the training loss only, as in the reference). After `replan_steps` steps
    without progress its reach proposition is marked infeasible (every candidate reaching it) and
    the next best is taken, unless the last transition was accepting (staying is then the goal;
    the timer restarts). With no candidate left the agent gives the episode up (`aborted`, the
    reference's `NoPathsException`: neither success nor violation). Actions are the policy's
    mode (`deterministic`, the reference's setting) or samples.
    """
    alphabet = jnp.asarray(alphabet, bool)

    def plan(params, obs, task_state, infeasible, masks):
        reach, avoid, valid = masks
        images = jax.vmap(reduce_observation, in_axes=(None, 0, 0))(obs, reach, avoid)
        out = network.apply(params, images)
        score = out.value - out.multiplier * out.cost_value
        allowed = valid & ~infeasible
        best = jnp.argmax(jnp.where(allowed, score, -jnp.inf))
        return PlanCarry(task_state.q, reach[best], avoid[best], best.astype(jnp.int32), infeasible,
                         jnp.zeros((), jnp.int32), ~jnp.any(allowed))

    def init(params, obs, task_state, key):
        num = task_state.spec.seq_valid.shape[1] * alphabet.shape[1]
        masks = candidate_masks(task_state.spec, task_state.q, alphabet)
        return plan(params, obs, task_state, jnp.zeros(num, bool), masks)

    def apply(params, obs, task_state, carry: PlanCarry, key):
        spec, q = task_state.spec, task_state.q
        moved = q != carry.q
        timed_out = (carry.steps >= replan_steps) & ~moved
        symbol = label_symbol(alphabet, task_state.propositions)
        give_up = timed_out & ~spec.accepting[q, symbol]
        # A timeout gives up the reach proposition itself (every candidate that shares it), as
        # the reference marks the reach assignment infeasible at the current automaton state.
        masks = candidate_masks(spec, q, alphabet)
        same_reach = jnp.all(masks[0] == carry.reach, axis=-1)
        infeasible = jnp.where(moved, False, carry.infeasible) | (give_up & same_reach)
        carry = jax.lax.cond(
            moved | give_up,
            lambda: plan(params, obs, task_state, infeasible, masks),
            lambda: carry._replace(steps=jnp.where(timed_out, 0, carry.steps)),
        )
        out = network.apply(params, reduce_observation(obs, carry.reach, carry.avoid))
        action = out.pi.mode() if deterministic else out.pi.sample(key)
        return action, carry._replace(steps=carry.steps + 1)

    return StatefulPolicy(init, apply, aborted=lambda carry: carry.stuck)
