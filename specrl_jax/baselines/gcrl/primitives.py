"""GCRL-LTL's direction primitives for robot worlds: four frozen low-level policies (+x, -x, +y,
-y) that the goal-conditioned policy chooses among (`Discrete(4)`).

Each primitive maps the robot's own sensors (`obs["ego"]` without the wall sensor: Point 12,
Car 24, Ant 40 values) to an action, SB3's `MlpPolicy` shape: actor and critic MLPs [64, 64]
Tanh, a Gaussian with a state-independent log-std. They train with the shared PPO in the robot's
world with the zones ignored (labels unused, no zone reward), 300-step episodes, reward
`v . d - 0.05 |v . d_perp|` (world-frame velocity of the robot body along the direction, minus
the orthogonal speed), all four side by side under `vmap`. The GCRL policy then applies the
chosen primitive's mean action times a temperature (1.25 in training, 1.5 at test time, the
original's), clipped to the action box.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax import cache
from specrl_jax.baselines.ppo.networks import MLP, DiagGaussian, PolicyOutput, critic, dense
from specrl_jax.baselines.ppo.rollout import StepResult
from specrl_jax.baselines.ppo.train import Method, PPOConfig, make_train
from specrl_jax.baselines.runs import init_seeds, train_chunks
from specrl_jax.envs.spaces import Discrete
from specrl_jax.envs.wrappers import Wrapper, reset_done
from specrl_jax.tasks.sources import ByContent

#: float32[4, 2]: the directions pos_x, neg_x, pos_y, neg_y (world frame)
DIRECTIONS = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]], np.float32)
ORTHOGONAL_PENALTY = 0.05
HORIZON = 300
TRAIN_TEMPERATURE = 1.25
EVAL_TEMPERATURE = 1.5
MAX_STEPS = 1_000_000  # per primitive (the original's checkpoints: about 1M)


class PrimitiveNetwork(nn.Module):
    """Actor MLP [64, 64] Tanh -> Gaussian mean with a state-independent log-std; critic MLP
    [64, 64] Tanh -> 1, on the robot sensors float32[..., E]."""

    action_dim: int

    @nn.compact
    def __call__(self, sensors: jax.Array) -> PolicyOutput:
        mean = dense(self.action_dim, gain=0.01)(MLP((64, 64), "tanh")(sensors))
        log_std = self.param("log_std", nn.initializers.zeros_init(), (self.action_dim,))
        value = critic((64, 64), "tanh")(sensors)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(DiagGaussian(mean, jnp.broadcast_to(jnp.exp(log_std), mean.shape)),
                            value, zeros, zeros)


def robot_sensors(world: Any, obs: dict[str, jax.Array]) -> jax.Array:
    """float32[..., E]: the robot's own sensors (the wall sensor left out)."""
    return obs["ego"][..., : world.robot.ego_size].astype(jnp.float32)


def primitive_action(network: PrimitiveNetwork, primitives: Any, index: jax.Array,
                     sensors: jax.Array, temperature: float) -> jax.Array:
    """The mean action of primitive `index` (int32[]) times `temperature`, clipped to [-1, 1];
    `primitives` holds the four primitives' parameters on a leading axis."""
    params = jax.tree.map(lambda x: jnp.asarray(x)[index], primitives)
    return jnp.clip(network.apply(params, sensors).pi.mean * temperature, -1.0, 1.0)


@dataclasses.dataclass(frozen=True)
class DirectionEnv:
    """The primitives' training env (`rollout.TrainEnv`; `task_params` = the direction,
    int32[]): the world with its own resets and terminations, episodes of `HORIZON` steps."""

    world: Any
    params: Any

    def reset(self, key: jax.Array, task_params: Any) -> tuple[jax.Array, Any]:
        obs, state = self.world.reset(key, self.params)
        return robot_sensors(self.world, obs), state

    def step(self, key: jax.Array, state: Any, action: jax.Array, direction: jax.Array):
        key_step, key_reset = jax.random.split(key)
        obs, stepped, _, terminated, truncated, info = self.world.step(
            key_step, state, jnp.clip(action, -1.0, 1.0), self.params)
        moved = stepped.physics.agent_pos[:2] - state.physics.agent_pos[:2]
        velocity = moved / self.world.frame_dt  # m/s, world frame
        d = jnp.asarray(DIRECTIONS)[direction]
        along = velocity @ d
        across = jnp.abs(velocity @ jnp.stack([-d[1], d[0]]))
        reward = along - ORTHOGONAL_PENALTY * across
        done = terminated | truncated
        obs, stepped, info = reset_done(done, lambda k: self.world.reset(k, self.params),
                                        key_reset, obs, stepped, info)
        f32 = lambda x: jnp.asarray(x, jnp.float32)
        result = StepResult(
            reward=f32(reward), cost=f32(0.0), terminated=terminated, truncated=truncated,
            cut=jnp.zeros((), bool), final_obs=robot_sensors(self.world, info["final_observation"]),
            stats={"episodes": f32(done), "speed_along": f32(along)})
        return robot_sensors(self.world, obs), stepped, result


def direction_env(world: Any, params: Any) -> DirectionEnv:
    """The primitives' training env over `world` with its params' horizon set to `HORIZON`."""
    return DirectionEnv(world, params.replace(max_steps=HORIZON))


@dataclasses.dataclass(frozen=True)
class PrimitiveMethod(Method):
    """One direction primitive for the shared trainer (the direction is the runner's
    `task_params`, set per primitive by `train_primitives`)."""

    env: DirectionEnv
    network: PrimitiveNetwork

    def init_task_params(self) -> jax.Array:
        return jnp.int32(0)

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return task_params


def ppo_config(total_timesteps: int = MAX_STEPS, **overrides: Any) -> PPOConfig:
    """The primitives' PPO (the original's SB3 settings: 10 epochs, lr 3e-4, gamma 0.99, GAE
    0.95, clip 0.2 without value clipping, no entropy bonus, normalised advantages, Adam eps
    1e-5), in 64 envs x 128 steps with minibatches of 512 (the original: 4 x 2048, minibatch
    64)."""
    settings = {"num_envs": 64, "num_steps": 128, "num_minibatches": 16, "update_epochs": 10,
                "lr": 3e-4, "adam_eps": 1e-5, "gamma": 0.99, "gae_lambda": 0.95, "clip_eps": 0.2,
                "ent_coef": 0.0, "entropy_per_action_dim": False,  # SB3's (no bonus here)
                "vf_coef": 0.5, "clip_value": False, "normalize_advantages": True,
                "total_timesteps": int(total_timesteps)}
    return PPOConfig(**{**settings, **overrides})


def init_primitives(world: Any, key: jax.Array) -> Any:
    """Untrained parameters of the four primitives (leading axis 4), e.g. as a shape template."""
    network = PrimitiveNetwork(int(world.action_space.shape[0]))
    sensors = jnp.zeros((1, world.robot.ego_size), jnp.float32)
    return jax.vmap(lambda k: network.init(k, sensors))(jax.random.split(key, len(DIRECTIONS)))


def train_primitives(world: Any, params: Any, key: jax.Array, config: PPOConfig,
                     log: Callable[[str], None] = print) -> Any:
    """Train the four primitives side by side with the shared PPO; returns their parameters
    (leading axis 4, in `DIRECTIONS` order)."""
    method = PrimitiveMethod(direction_env(world, params),
                             PrimitiveNetwork(int(world.action_space.shape[0])))
    trainer = make_train(config, method)
    start = init_seeds(trainer, key, len(DIRECTIONS))
    start = start.replace(task_params=jnp.arange(len(DIRECTIONS), dtype=jnp.int32))
    # the run driver, the four directions on its seed axis, all updates in one chunk
    (runners, metrics, _, _), = train_chunks(trainer, start, len(DIRECTIONS),
                                             config.num_updates, config.num_updates)
    speed = np.asarray(metrics["speed_along"]) / config.batch_size  # [4, updates], m/s
    tail = max(1, speed.shape[1] // 10)
    log(f"direction primitives: {config.num_updates} updates x {config.batch_size} steps each; "
        f"mean speed along +x -x +y -y {np.round(speed[:, :tail].mean(1), 3).tolist()} -> "
        f"{np.round(speed[:, -tail:].mean(1), 3).tolist()} m/s")
    return runners.params


def cached_primitives(world: Any, params: Any, key: jax.Array, config: PPOConfig, template: Any,
                      log: Callable[[str], None] = print) -> Any:
    """`train_primitives(world, params, key, config, log)`, read from the disk cache
    (`cache.tables_dir()`, in `template`'s structure) when an identical training stored them
    there; the entry is named by the world (class, config, physics and params, its reset bank
    among them), the key, the PPO settings, every file of the package and the versions and
    devices (`cache.runtime`). A world defined outside the package is trained every time."""
    if not cache.in_package(type(world)):
        return train_primitives(world, params, key, config, log)
    name = "gcrl_primitives_" + cache.digest({
        "world": f"{type(world).__module__}.{type(world).__qualname__}",
        "config": repr(getattr(world, "config", None)),
        "physics": getattr(getattr(world, "physics", None), "backend", None),
        "params": ByContent(params).digest, "key": np.asarray(jax.random.key_data(key)).tolist(),
        "ppo": dataclasses.asdict(config), "package": cache.package_digest(),
        "runtime": cache.runtime()})
    stored = cache.load_tree(cache.tables_dir(), name, template)
    if stored is not None:
        log(f"direction primitives read from the cache: {cache.tables_dir()}/{name}.npz")
        return stored
    trained = train_primitives(world, params, key, config, log)
    cache.save_tree(cache.tables_dir(), name, trained)
    return trained


@struct.dataclass
class PrimitiveState:
    world: Any  # the world's state
    sensors: jax.Array  # float32[E], the robot sensors of the last observation


class PrimitiveWorld(Wrapper):
    """A robot world whose action is the index of a frozen primitive (`Discrete(4)`): the
    primitive's mean action on the last robot sensors, times `temperature`, steps the world."""

    def __init__(self, world: Any, primitives: Any, temperature: float = TRAIN_TEMPERATURE):
        super().__init__(world)
        self.primitives = primitives
        self.temperature = temperature
        self.network = PrimitiveNetwork(int(world.action_space.shape[0]))

    @property
    def action_space(self) -> Discrete:
        return Discrete(len(DIRECTIONS))

    def reset(self, key: jax.Array, params: Any = None) -> tuple[Any, PrimitiveState]:
        obs, state = self.env.reset(key, params)
        return obs, PrimitiveState(state, robot_sensors(self.env, obs))

    def step(self, key: jax.Array, state: PrimitiveState, action: jax.Array, params: Any = None):
        move = primitive_action(self.network, self.primitives, action, state.sensors,
                                self.temperature)
        obs, world_state, reward, terminated, truncated, info = self.env.step(
            key, state.world, move, params)
        return (obs, PrimitiveState(world_state, robot_sensors(self.env, obs)), reward, terminated,
                truncated, info)
