"""GCRL-LTL (Qiu, Mao, Zhu, NeurIPS'23): a goal-conditioned policy, a goal-conditioned value
function, and a value-weighted search over the automaton at test time.

1. The policy reaches one proposition at a time. It reads the world observation and a fixed
   random 24-d vector of its goal proposition; the net is the original's: a linear feature
   layer as wide as its input, a shared ReLU trunk [512, 1024, 256], logits and value heads.
   It trains with the shared PPO on the task loop with one-goal tasks (the one-step subgoal
   source GenZ-LTL draws from, with no avoid set): reward 1 and the end of the episode on
   entering the goal, 0 otherwise; other propositions are not penalised.
2. The goal-conditioned value function (GCVF, `train_value_function`) regresses, from states of
   the trained policy's successful trajectories (one in ten kept), the critic's value of every
   other goal: input `state ++ vec(goal) ++ vec(other goal)`, MLP 4 x 1024 ReLU, L1 loss.
3. At test time (`make_policy`) the path-graph search (`gcrl_search`) picks the next goal with
   edge costs `1 - V` (critic for the first goal, GCVF for pairs), and the original's safety
   rule composes the action when an avoided proposition looks closer than the goal.

LetterWorld uses the project's grid encoder and the world's 4 moves. Zone robots act, as the
original, through 4 frozen direction primitives (`gcrl_primitives`), trained on device before the
policy (`prepare_training`); other continuous worlds (the arm) get a Gaussian head.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from specrl_jax import families
from specrl_jax.baselines.compile_log import compile_logged
from specrl_jax.baselines.encoders import ObsEncoder, check_image_dtype, check_kinds, obs_parts
from specrl_jax.baselines.gcrl import primitives as primitives_lib
from specrl_jax.baselines.gcrl import search
from specrl_jax.baselines.params_io import kept_params
from specrl_jax.baselines.ppo.networks import (
    DiscreteHead,
    GaussianHead,
    PolicyOutput,
)
from specrl_jax.baselines.ppo.rollout import reset_batch
from specrl_jax.baselines.ppo.train import Method, PPOConfig, world_config
from specrl_jax.baselines.runs import seed_keys
from specrl_jax.baselines.spec import MethodSpec
from specrl_jax.baselines.train_env import TaskTrainEnv
from specrl_jax.specs import CurriculumSampler
from specrl_jax.specs.curricula import Curriculum, GenZSubgoals, Stage
from specrl_jax.tasks import SequenceSource, StatefulPolicy, TaskEnv

GOAL_DIM = 24
GOAL_SEED = 20231
VALUE_THRESHOLD = 0.85
#: the GCVF rollouts' stored states (bytes) of the seeds fitted side by side, at most: the peak
#: is about twice that; three seeds of a 64 x 64 camera's (18.9 GB) ran an H200 out of memory,
#: asking for 35 GiB more, where two (12.7 GB) fitted
GCVF_BATCH_BYTES = 8 * 2**30
PLANNERS = ("intended", "as_coded")  # test-time search: the original's description, or its code
#: one-goal training tasks: reach one proposition, avoid nothing, uniformly over propositions
REACH_ONE = Curriculum("gcrl/reach", (Stage((GenZSubgoals(max_avoid=0),)),))


def goal_vectors(num_props: int) -> np.ndarray:
    """float32[P, 24]: the fixed goal vector of each proposition (uniform in [-1, 1), drawn once
    from a fixed seed; the original hard-codes its own random numbers)."""
    return np.random.default_rng(GOAL_SEED).uniform(-1, 1, (num_props, GOAL_DIM)).astype(np.float32)


class GoalObs(NamedTuple):
    """What the GCRL network reads (one env; leading batch axes allowed): `parts` the world
    observation as encoder parts (`encoders.obs_parts`), `goal` float32[24] the goal's vector,
    `goal_index` int32[] the goal proposition (not read by the network)."""

    parts: dict
    goal: jax.Array
    goal_index: jax.Array


def dense(features: int, gain: float) -> nn.Dense:
    return nn.Dense(features, kernel_init=nn.initializers.orthogonal(gain))


class GCRLNetwork(nn.Module):
    """Observation ++ goal vector -> linear features (as wide as the input) -> shared trunk
    [512, 1024, 256] ReLU -> logits (or a Gaussian) and value. SB3's orthogonal init: gain
    sqrt(2) hidden, 0.01 logits, 1 value."""

    num_actions: int  # discrete actions, or the action dimension when `continuous`
    continuous: bool = False
    trunk: tuple[int, ...] = (512, 1024, 256)
    primitive_sensors: int = 0  # > 0: the actions are direction primitives on this many sensors
    image_dtype: str = "float32"

    @nn.compact
    def __call__(self, obs: GoalObs) -> PolicyOutput:
        # grid parts -> the LetterWorld CNN, images -> the camera CNN, vectors as they are (the
        # original feeds the raw sensor vector)
        parts = ObsEncoder(vector_features=(), image_dtype=self.image_dtype,
                           name="GoalEncoder_0")(obs.parts)
        x = jnp.concatenate([parts, obs.goal.astype(jnp.float32)], axis=-1)
        x = dense(x.shape[-1], np.sqrt(2))(x)
        for width in self.trunk:
            x = nn.relu(dense(width, np.sqrt(2))(x))
        head = GaussianHead if self.continuous else DiscreteHead
        pi = head(self.num_actions)(x)
        value = dense(1, 1.0)(x)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(pi, value, zeros, zeros)


class ValueFunction(nn.Module):
    """The GCVF: MLP [1024] x 4 ReLU -> 1 on `state ++ vec(g1) ++ vec(g2)`."""

    features: tuple[int, ...] = (1024, 1024, 1024, 1024)

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.features:
            x = nn.relu(nn.Dense(width)(x))
        return nn.Dense(1)(x)[..., 0]


def flat_state(parts: Mapping[str, jax.Array]) -> jax.Array:
    """float32[D]: the encoder parts flattened and concatenated (sorted by name), the GCVF's
    state input."""
    return jnp.concatenate([parts[k].astype(jnp.float32).reshape(-1) for k in sorted(parts)])


def network_for(world: Any, trunk: tuple[int, ...] = (512, 1024, 256),
                hierarchical: bool = False, image_dtype: str = "float32") -> GCRLNetwork:
    """The GCRL network for a world's action space; `hierarchical`: logits over the 4 direction
    primitives of a robot world (`gcrl_primitives`)."""
    check_kinds(world.obs_kinds)
    space, image_dtype = world.action_space, check_image_dtype(image_dtype)
    if hierarchical:
        return GCRLNetwork(len(primitives_lib.DIRECTIONS), trunk=trunk,
                           primitive_sensors=int(world.robot.ego_size), image_dtype=image_dtype)
    if hasattr(space, "n"):
        return GCRLNetwork(int(space.n), trunk=trunk, image_dtype=image_dtype)
    return GCRLNetwork(int(space.shape[0]), continuous=True, trunk=trunk, image_dtype=image_dtype)


def uses_primitives(world: Any, family: str) -> bool:
    """Robot worlds of the Zone family act through direction primitives (the original's)."""
    return family == "zone" and not hasattr(world.action_space, "n")


@dataclasses.dataclass(frozen=True)
class GCRL(Method):
    """The GCRL-LTL method for the shared trainer: the task loop with one-goal tasks."""

    env: TaskTrainEnv
    network: GCRLNetwork
    family: str = "letter"
    value_network: ValueFunction = ValueFunction()
    world: Any = None  # the world itself (`env.task.env` wraps it with primitives)
    primitives: Any = None  # the frozen primitives' parameters (leading axis 4), or None

    def init_task_params(self) -> Any:
        return self.env.task.source.init_params()

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return task_params


def make_method(world: Any, params: Any, family: str | None = None,
                trunk: tuple[int, ...] = (512, 1024, 256),
                value_features: tuple[int, ...] = (1024,) * 4, primitives: Any = None,
                image_dtype: str = "float32") -> GCRL:
    """GCRL-LTL on any single-agent world: one-goal tasks over the world's propositions. Zone
    robots act through the 4 direction primitives `primitives` (untrained placeholders when
    None: `prepare_training` trains them). `image_dtype`: the image CNN's convolutions."""
    family = families.name_of(world, family)
    hierarchical = uses_primitives(world, family)
    network = network_for(world, trunk, hierarchical, image_dtype)
    if hierarchical and primitives is None:
        primitives = primitives_lib.init_primitives(world, jax.random.key(0))
    acting = primitives_lib.PrimitiveWorld(world, primitives) if hierarchical else world
    alphabet = jnp.asarray(world.alphabet, bool)
    goals = jnp.asarray(goal_vectors(world.num_propositions))
    source = SequenceSource(CurriculumSampler(REACH_ONE, world.num_propositions), alphabet)
    kinds = dict(world.obs_kinds)

    def observe(obs, state):
        reach, _ = state.task.current_masks(alphabet)
        goal = jnp.argmax(reach).astype(jnp.int32)
        return GoalObs(obs_parts(obs, kinds), goals[goal], goal)

    def signals(info):
        reward = info["success"].astype(jnp.float32)
        return reward, jnp.zeros((), jnp.float32), jnp.zeros((), bool)

    task = TaskEnv(acting, source, observe)
    return GCRL(TaskTrainEnv(task, params, signals), network, family,
                ValueFunction(value_features), world, primitives if hierarchical else None)


def summarise(row: dict[str, float]) -> dict[str, float]:
    episodes = max(row["episodes"], 1.0)
    return {**row, "success_rate": row["successes"] / episodes}


def ppo_config(world: str = "letter", **overrides: Any) -> PPOConfig:
    """The world's shared shapes and discount with GCRL-LTL's SB3 settings: 10 epochs, GAE 0.95,
    clip 0.2 without value clipping, value coefficient 0.5, normalised advantages, Adam eps 1e-5,
    lr 3e-4."""
    return world_config(world, {"update_epochs": 10, "loss": "ppo", "vf_coef": 0.5,
                                "gae_lambda": 0.95, "lr": 3e-4, "adam_eps": 1e-5,
                                "clip_value": False, "normalize_advantages": True}, **overrides)


# ---------------------------------------------------------------------------------------------
# The goal-conditioned value function, from rollouts of the trained policy


@dataclasses.dataclass(frozen=True)
class ValueConfig:
    """GCVF data and regression settings (the original: keep 1 in 10 successful trajectories,
    batch 512, Adam 4e-4, L1 loss)."""

    num_envs: int = 128
    num_steps: int = 256
    keep_prob: float = 0.1
    batch_size: int = 512
    num_updates: int = 10_000
    lr: float = 4e-4

    def __post_init__(self) -> None:
        for name in ("num_envs", "num_steps", "batch_size", "num_updates"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if not 0.0 < self.keep_prob <= 1.0:
            raise ValueError(f"keep_prob must be in (0, 1], got {self.keep_prob!r}")


class ValueData(NamedTuple):
    """The GCVF dataset: `state` float32[N, D], `goal` int32[N] the goal being pursued,
    `label` float32[N, P] the critic's value of each goal there, `valid` bool[N, P] the pair is
    a sample (kept successful trajectory, other goal)."""

    state: jax.Array
    goal: jax.Array
    label: jax.Array
    valid: jax.Array


def collect_value_data(method: GCRL, policy_params: Any, key: jax.Array, cfg: ValueConfig
                       ) -> ValueData:
    """Roll the trained policy (sampled actions) in `cfg.num_envs` envs for `cfg.num_steps` steps
    and label the states of the trajectories that reached their goal (each kept with
    probability `keep_prob`) with the critic's value of every other goal."""
    env, network = method.env, method.network
    goals = jnp.asarray(goal_vectors(env.task.env.num_propositions))
    num_goals = goals.shape[0]
    key_reset, key_run, key_keep = jax.random.split(key, 3)
    task_params = method.init_task_params()
    obs, state = reset_batch(env, key_reset, cfg.num_envs, task_params)
    step_batch = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def one_step(carry, key_step):
        state, obs = carry
        key_action, key_env = jax.random.split(key_step)
        action = network.apply(policy_params, obs).pi.sample(key_action)
        next_obs, state, result = step_batch(jax.random.split(key_env, cfg.num_envs), state,
                                             action, task_params)
        values = jax.vmap(lambda g: network.apply(policy_params, obs._replace(
            goal=jnp.broadcast_to(goals[g], obs.goal.shape))).value)(jnp.arange(num_goals))
        record = (jax.vmap(flat_state)(obs.parts), obs.goal_index, values.T,
                  result.stats["_success"], result.stats["_finished"])
        return (state, next_obs), record

    _, (states, goal, label, success, done) = jax.lax.scan(
        one_step, (state, obs), jax.random.split(key_run, cfg.num_steps))
    draw = jax.random.uniform(key_keep, done.shape)

    def backward(carry, xs):  # does this step's episode end in success, and its keep draw
        ahead, u = carry
        success_t, done_t, draw_t = xs
        ahead = success_t | (~done_t & ahead)
        u = jnp.where(done_t, draw_t, u)
        return (ahead, u), ahead & (u < cfg.keep_prob)

    init = (jnp.zeros(cfg.num_envs, bool), draw[-1])
    _, keep = jax.lax.scan(backward, init, (success, done, draw), reverse=True)
    valid = keep[..., None] & (goal[..., None] != jnp.arange(num_goals))
    flat = lambda x: x.reshape(-1, *x.shape[2:])
    return ValueData(flat(states), flat(goal), flat(label), flat(valid))


def fit_value_function(method: GCRL, data: ValueData, key: jax.Array, cfg: ValueConfig
                       ) -> tuple[Any, jax.Array]:
    """L1 regression of the GCVF on `data`, minibatches drawn with replacement from the valid
    pairs. Returns `(params, loss float32[num_updates])` (all losses 0 without data)."""
    goals = jnp.asarray(goal_vectors(data.label.shape[1]))
    num_goals = goals.shape[0]
    valid = data.valid.reshape(-1)
    order = jnp.argsort(~valid, stable=True)  # the valid pairs first
    count = jnp.sum(valid)
    net = method.value_network

    def inputs(pair):
        row, other = pair // num_goals, pair % num_goals
        x = jnp.concatenate([data.state[row], goals[data.goal[row]], goals[other]], axis=-1)
        return x, data.label[row, other]

    key_init, key_run = jax.random.split(key)
    params = net.init(key_init, inputs(jnp.zeros(1, jnp.int32))[0])
    optimizer = optax.adam(cfg.lr)

    def update(carry, key_batch):
        params, opt_state = carry
        pick = jax.random.randint(key_batch, (cfg.batch_size,), 0, jnp.maximum(count, 1))
        x, y = inputs(order[pick])

        def loss_of(p):
            return jnp.mean(jnp.abs(net.apply(p, x) - y)) * (count > 0)

        loss, grads = jax.value_and_grad(loss_of)(params)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), loss

    (params, _), losses = jax.lax.scan(update, (params, optimizer.init(params)),
                                       jax.random.split(key_run, cfg.num_updates))
    return params, losses


def train_value_function(method: GCRL, policy_params: Any, key: jax.Array,
                         cfg: ValueConfig = ValueConfig()) -> tuple[Any, dict[str, jax.Array]]:
    """Collect the dataset with the trained policy and fit the GCVF (jit/vmap-able)."""
    key_data, key_fit = jax.random.split(key)
    data = collect_value_data(method, policy_params, key_data, cfg)
    params, losses = fit_value_function(method, data, key_fit, cfg)
    tail = max(1, cfg.num_updates // 10)
    return params, {"samples": jnp.sum(data.valid), "loss_first": losses[:tail].mean(),
                    "loss_last": losses[-tail:].mean()}


def value_config(method: GCRL, total_timesteps: int) -> ValueConfig:
    """GCVF settings for a run of `total_timesteps` PPO steps: one regression step per 1,500
    training steps, at most 10,000 (15M steps: 10,000); one rollout env per 100,000 training
    steps, between 8 and 128; rollouts as long as the world's horizon (at least 256 steps) so
    that trajectories complete."""
    horizon = int(method.env.params.max_steps)
    return ValueConfig(num_envs=int(min(128, max(8, total_timesteps // 100_000))),
                       num_steps=max(256, horizon),
                       num_updates=int(min(10_000, max(1, total_timesteps // 1500))))


def prepare_training(method: GCRL, key: jax.Array, config: PPOConfig,
                     log: Callable[[str], None] = print, saved: Path | None = None) -> GCRL:
    """Before PPO: train the direction primitives of a robot world (one primitive step per 15
    training steps, at most 1M each; 15M: 1M) and return the method acting through them.
    `saved`: the primitives' file in the run directory, read when there (a resumed run),
    else written; an identical run's primitives are read from the disk cache
    (`primitives.cached_primitives`)."""
    if method.primitives is None:
        return method
    steps = int(min(primitives_lib.MAX_STEPS, max(1, config.total_timesteps // 15)))
    trained = kept_params(saved, lambda: primitives_lib.cached_primitives(
        method.world, method.env.params, jax.random.fold_in(key, 4),
        primitives_lib.ppo_config(steps), method.primitives, log), method.primitives,
        "direction primitives", log)
    return make_method(method.world, method.env.params, method.family, method.network.trunk,
                       method.value_network.features, primitives=trained,
                       image_dtype=method.network.image_dtype)


def gcvf_seeds_at_once(method: GCRL, cfg: ValueConfig, num_seeds: int) -> int:
    """How many seeds' GCVFs collect and fit side by side: all, unless their rollouts' states
    (float32[num_steps, num_envs, D] a seed) pass `GCVF_BATCH_BYTES` together; at least one.
    For a 15M-step run on a 1,000-step Zone world (128 envs x 1,000 steps) a 64 x 64 camera's
    take 6.3 GB a seed, LiDAR's 0.04-0.06 GB, so LiDAR seeds fit together, camera seeds one
    at a time."""
    per_seed = cfg.num_envs * cfg.num_steps * state_width(method) * 4
    return int(max(1, min(num_seeds, GCVF_BATCH_BYTES // per_seed)))


def finish_training(method: GCRL, params: Any, key: jax.Array, config: PPOConfig,
                    log: Callable[[str], None] = print, program_key: str | None = None,
                    first_seed: int = 1) -> dict[str, Any]:
    """After PPO: train each seed's GCVF (leading seed axis on `params`, seeds `first_seed` on),
    `gcvf_seeds_at_once` of them side by side; returns `{"policy": params, "gcvf": gcvf
    params}`, what `make_policy` reads. `program_key` names the traced program on disk
    (`compile_logged`)."""
    cfg = value_config(method, config.total_timesteps)
    num_seeds = jax.tree.leaves(params)[0].shape[0]
    keys = seed_keys(jax.random.fold_in(key, 15), num_seeds, first_seed)
    side_by_side = gcvf_seeds_at_once(method, cfg, num_seeds)
    train = compile_logged(
        lambda ps, ks: jax.lax.map(lambda pk: train_value_function(method, *pk, cfg), (ps, ks),
                                   batch_size=side_by_side),
        (params, keys), "the GCVF's data collection and fit", log, program_key)
    gcvf, stats = jax.device_get(train(params, keys))
    log(f"GCVF ({side_by_side} seed(s) side by side): {cfg.num_updates} updates on "
        f"{[int(s) for s in stats['samples']]} samples per seed; L1 loss "
        f"{np.round(stats['loss_first'], 4).tolist()} -> "
        f"{np.round(stats['loss_last'], 4).tolist()}")
    out = {"policy": params, "gcvf": gcvf}
    if method.primitives is not None:  # one frozen set, repeated along the seed axis
        out["primitives"] = jax.tree.map(
            lambda x: np.broadcast_to(np.asarray(x), (num_seeds, *np.shape(x))), method.primitives)
    return out


def state_width(method: GCRL) -> int:
    """Length of the flat observation the GCVF reads (`flat_state` of the parts)."""
    obs, _ = jax.eval_shape(method.env.reset, jax.random.key(0), method.init_task_params())
    return sum(int(np.prod(x.shape)) for x in jax.tree.leaves(obs.parts))


def param_shapes(method: GCRL, policy_shapes: Any) -> dict[str, Any]:
    """The shapes of `finish_training`'s parameters for one seed, from the policy's."""
    width = state_width(method) + 2 * GOAL_DIM
    gcvf = jax.eval_shape(method.value_network.init, jax.random.key(0),
                          jax.ShapeDtypeStruct((1, width), jnp.float32))
    out = {"policy": policy_shapes, "gcvf": gcvf}
    if method.primitives is not None:
        out["primitives"] = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype),
                                         method.primitives)
    return out


# ---------------------------------------------------------------------------------------------
# Test time: search for the next goal, act with the safety rule


def goal_outputs(network: nn.Module, params: Any, parts: Mapping[str, jax.Array],
                 goals: jax.Array) -> PolicyOutput:
    """The network on one observation's `parts` with every goal: outputs with a leading axis P."""
    num_props = goals.shape[0]
    batch = GoalObs(jax.tree.map(lambda x: jnp.broadcast_to(x, (num_props, *x.shape)), parts),
                    goals, jnp.arange(num_props, dtype=jnp.int32))
    return network.apply(params, batch)


def safe_action(network: nn.Module, out: PolicyOutput, goal: jax.Array, avoid: jax.Array,
                value_threshold: float, deterministic: bool, key: jax.Array,
                primitives: Any = None, sensors: jax.Array | None = None,
                temperature: float = primitives_lib.EVAL_TEMPERATURE) -> jax.Array:
    """The world action by the original's safety rule, on `goal_outputs`.

    When some avoided proposition has `V(s, p) > value_threshold` and above the goal's value,
    turn away from the most dangerous one: with direction primitives, the sum of the primitive
    least likely toward it and the goal's best primitive other than the one most likely toward
    it (the original's: the two clipped mean actions summed, times `temperature`, clipped);
    on a grid, that goal move alone; with a continuous head, the goal's
    mean action minus the danger's. Otherwise the goal's mode (`deterministic`) or a sample.
    `goal` int32[] (-1: none; then the agent pursues the first proposition it need not avoid, and
    turns away from the danger alone). `primitives`, `sensors`: the primitives' parameters and the robot sensors, for a primitive network;
    `temperature` scales their actions (the original's 1.5 at test time).
    """
    index = jnp.where(goal >= 0, goal, jnp.argmax(~avoid))
    danger = jnp.where(avoid, out.value, -jnp.inf)
    worst = jnp.argmax(danger)
    has_goal = goal >= 0
    turn = (danger[worst] > value_threshold) & ((danger[worst] > out.value[index]) | ~has_goal)
    pi = jax.tree.map(lambda x: x[index], out.pi)
    chosen = pi.mode() if deterministic else pi.sample(key)
    if network.continuous:
        away = jnp.clip(out.pi.mean[index] * has_goal - out.pi.mean[worst], -1.0, 1.0)
        return jnp.where(turn, away, chosen)
    toward = jnp.argmax(out.pi.logits[worst])
    actions = jnp.arange(out.pi.logits.shape[-1])
    masked = jnp.where(actions == toward, -jnp.inf, out.pi.logits[index])
    other, safe = jnp.argmax(masked), jnp.argmin(out.pi.logits[worst])
    if not network.primitive_sensors:
        return jnp.where(turn, jnp.where(has_goal, other, safe), chosen).astype(chosen.dtype)
    action_dim = primitives["params"]["log_std"].shape[-1]
    prim = primitives_lib.PrimitiveNetwork(action_dim)
    move = lambda i, t: primitives_lib.primitive_action(prim, primitives, i, sensors, t)
    # the original sums the two primitives' actions (each clipped to the box) before scaling
    summed = jnp.where(has_goal, move(other, 1.0), 0.0) + move(safe, 1.0)
    composed = jnp.clip(temperature * summed, -1.0, 1.0)
    return jnp.where(turn, composed, move(chosen, temperature))


def _sensors(network: nn.Module, obs: Mapping[str, jax.Array]) -> jax.Array | None:
    """The robot sensors a primitive network reads (`obs["ego"]` without the wall sensor)."""
    if not getattr(network, "primitive_sensors", 0):
        return None
    return obs["ego"][..., : network.primitive_sensors].astype(jnp.float32)


def coordinator_agent(network: nn.Module, obs_kinds: Mapping[str, str],
                      value_threshold: float = VALUE_THRESHOLD):
    """GCRL-LTL on one agent of the multi-agent coordinator (`tasks.coordinator`): the first
    proposition of its reach set is the goal, its avoid set feeds the safety rule; mode actions.
    Params `{"policy", "gcvf"}` (+ `"primitives"` on robot worlds; the GCVF is not read: the
    coordinator plans)."""
    kinds = dict(obs_kinds)

    def act(params, obs, goal, key):
        goals = jnp.asarray(goal_vectors(goal.reach.shape[-1]))
        out = goal_outputs(network, params["policy"], obs_parts(obs, kinds), goals)
        index = jnp.where(jnp.any(goal.reach), jnp.argmax(goal.reach), -1)
        return safe_action(network, out, index, goal.avoid, value_threshold, True, key,
                           params.get("primitives"), _sensors(network, obs))

    return act


class GCRLCarry(NamedTuple):
    q: jax.Array  # int32[], automaton state the plan was made in (-1: none yet)
    last: jax.Array  # int32[], the last goal reached (P: none)
    goal: jax.Array  # int32[], the proposition pursued (-1: none needed)
    slot: jax.Array  # int32[], epsilon edge the plan takes first (-1: none)
    avoid: jax.Array  # bool[P], propositions leading to a violation from q
    to_go: jax.Array  # float32[N], the search's cost to go (episode's first observation)


def make_policy(network: nn.Module, alphabet: jax.Array, obs_kinds: Mapping[str, str],
                deterministic: bool = True, value_threshold: float = VALUE_THRESHOLD,
                omega: float = search.OMEGA,
                value_network: nn.Module = ValueFunction(),
                temperature: float = primitives_lib.EVAL_TEMPERATURE,
                planner: str = "intended") -> StatefulPolicy:
    """GCRL-LTL's test-time agent as a `StatefulPolicy`; params `{"policy", "gcvf"}`.

    At the episode's start the value map is read off the first observation (critic V(s, p) for
    every goal, GCVF for every pair) and the search's cost to go computed once. Whenever the
    automaton state changes or the goal is reached, the next step of the cheapest plan is chosen
    with the current critic values: a goal proposition, or an epsilon edge to take. Avoided
    propositions are those leading from the automaton state to a violation. Each step: if some
    avoided p has `V(s, p) > value_threshold` and above the goal's value, the action turns away
    from the most dangerous one (discrete: the goal's best action other than the one most likely
    toward it; continuous: the goal's mean action minus the danger's, clipped); otherwise the
    goal's mode (`deterministic`, the original's) or a sample. With no goal needed (a persistence
    task's accepting cycle) the agent pursues the first proposition it need not avoid, so that it
    keeps moving without nearing a danger, and turns away from any danger above the threshold.
    `temperature` scales the direction primitives' actions of a robot world (the original's 1.5).

    `planner`: "intended" (the default, above) or "as_coded", the original's code where it
    departs from its description (docs/fidelity.md "GCRL-LTL: edge cost", "avoid sets"): edge
    costs `min(1 - V(s0, p), 0)` (`search.cost_matrix(as_coded=True)`: fewest steps wins,
    values unread) and avoid sets of every proposition that would leave the automaton state
    (the negated propositions of the plan node's self-loop), not only those leading to a
    violation.
    """
    if planner not in PLANNERS:
        raise ValueError(f"GCRL-LTL planner {planner!r} is not one of {PLANNERS}")
    as_coded = planner == "as_coded"
    alphabet_np = np.asarray(alphabet, bool)
    num_props = alphabet_np.shape[1]
    goals = jnp.asarray(goal_vectors(num_props))
    rows_np, empty = search.goal_symbols(alphabet_np)
    rows, alphabet = jnp.asarray(rows_np), jnp.asarray(alphabet_np)
    kinds = dict(obs_kinds)

    def all_goals(params, parts):
        return goal_outputs(network, params["policy"], parts, goals)

    def init(params, obs, task_state, key):
        parts = obs_parts(obs, kinds)
        start = all_goals(params, parts).value
        grid = (num_props, num_props)
        state = flat_state(parts)
        pairs = jnp.concatenate([jnp.broadcast_to(state, (*grid, state.shape[0])),
                                 jnp.broadcast_to(goals[:, None], (*grid, GOAL_DIM)),
                                 jnp.broadcast_to(goals[None], (*grid, GOAL_DIM))], -1)
        pair_values = value_network.apply(params["gcvf"], pairs)
        costs = search.cost_matrix(start, pair_values, as_coded)
        to_go = search.cost_to_go(task_state.spec, costs, rows, empty, omega)
        minus = jnp.full((), -1, jnp.int32)
        return GCRLCarry(minus, jnp.int32(num_props), minus, minus, jnp.zeros(num_props, bool),
                         to_go)

    def replan(out, task_state, carry, last):
        spec, q = task_state.spec, task_state.q
        first_cost = search.cost_matrix(out.value, jnp.zeros((num_props, num_props)),
                                        as_coded)[num_props]
        step = search.first_step(spec, q, last, first_cost, carry.to_go, rows, empty)
        nxt = spec.delta[q, jnp.maximum(rows, 0)]
        avoid = (rows >= 0) & ((nxt != q) if as_coded else spec.violation[nxt])
        return GCRLCarry(q, last, step.goal, step.slot, avoid, carry.to_go)

    def apply(params, obs, task_state, carry: GCRLCarry, key):
        out = all_goals(params, obs_parts(obs, kinds))
        label = task_state.propositions
        single = jnp.sum(label) == 1
        last = jnp.where(single, jnp.argmax(label), carry.last).astype(jnp.int32)
        reached = (carry.goal >= 0) & label[jnp.maximum(carry.goal, 0)]
        moved = task_state.q != carry.q
        carry = jax.lax.cond(moved | reached, lambda: replan(out, task_state, carry, last),
                             lambda: carry._replace(last=last))
        action = safe_action(network, out, carry.goal, carry.avoid, value_threshold,
                             deterministic, key, params.get("primitives"), _sensors(network, obs),
                             temperature)
        return (action, carry.slot), carry

    return StatefulPolicy(init, apply)


SPEC = MethodSpec(
    name="gcrl", title="GCRL-LTL", make_method=make_method, ppo_config=ppo_config,
    make_policy=make_policy, summarise=summarise,
    options=("trunk", "value_features", "primitives", "image_dtype"),
    policy_options=lambda method: {"value_network": method.value_network},
    prepare_training=prepare_training, finish_training=finish_training,
    param_shapes=param_shapes, coordinator_agent=coordinator_agent,
)
