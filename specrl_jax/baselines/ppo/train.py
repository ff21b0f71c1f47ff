"""One PPO for every baseline, in the PureJaxRL shape: collect -> GAE -> epochs -> minibatches,
all inside one jitted `lax.scan`.

A method (see `Method`) supplies its training env, its network and its task distribution; the
trainer never changes per method. `make_train(config, method)` returns a `Trainer`, callable as
`train(key) -> (runner_state, metrics)` for a whole run (jit/vmap-able over seeds); `init` and
`updates` expose the same computation in chunks for progress display and checkpoints, `collect`
and `learn` an update's two halves (rollout, PPO step) for profiling.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.extend import core as jax_core
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from specrl_jax import families
from specrl_jax.baselines.ppo import losses, rollout


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Trainer settings; defaults are DeepLTL's LetterWorld reference (torch-ac conventions)."""

    num_envs: int = 16
    num_steps: int = 128
    total_timesteps: int = 15_000_000
    update_epochs: int = 8  # the maximum when `target_kl` is set
    num_minibatches: int = 8
    lr: float = 3e-4
    adam_eps: float = 1e-8
    max_grad_norm: float = 0.5
    gamma: float = 0.94
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    clip_value: bool = True
    normalize_advantages: bool = False
    timeouts_terminal: bool = True
    loss: str = "ppo"  # "ppo" or "rco" (GenZ-LTL)
    target_kl: float | None = None  # stop an update's epochs once the mean approx. KL exceeds it
    target_cost: float = -0.05
    multiplier_min: float = 0.01
    multiplier_max: float = 5.0
    # the entropy bonus per action dimension, as torch-ac's baselines average a Gaussian's
    # entropy (False: the joint entropy, SB3's)
    entropy_per_action_dim: bool = True
    # seeds side by side: learn one seed after the other, each stopping at its own `target_kl`
    # (under `vmap` every seed runs the epochs of the last to stop); the same updates
    learn_seeds_in_turn: bool = False

    def __post_init__(self) -> None:
        if self.loss not in losses.LOSSES:
            raise ValueError(f"loss must be one of {sorted(losses.LOSSES)}, got {self.loss!r}")
        for name in ("num_envs", "num_steps", "update_epochs", "num_minibatches", "total_timesteps"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise ValueError(
                f"num_envs * num_steps = {self.num_envs * self.num_steps} is not divisible by "
                f"num_minibatches = {self.num_minibatches}"
            )

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches

    @property
    def num_updates(self) -> int:
        return max(1, self.total_timesteps // self.batch_size)

    def loss_config(self) -> losses.LossConfig:
        fields = losses.LossConfig._fields
        return losses.LossConfig(**{f: getattr(self, f) for f in fields})


def world_config(world: str, method: dict[str, Any], **overrides: Any) -> PPOConfig:
    """The world family's reference settings (`families.get(world).ppo`), then a method's own
    settings, then `overrides`."""
    return PPOConfig(**{**families.get(world).ppo, **method, **overrides})


class Method:
    """What a baseline plugs into the trainer: its training env and network (attributes `env:
    rollout.TrainEnv`, `network: nn.Module`), and the hooks below; subclasses override those that
    differ from the defaults."""

    env: rollout.TrainEnv
    network: nn.Module

    def init_params(self, key: jax.Array, obs: Any) -> Any:
        """The network's initial parameters (a method with a pretrained part overrides this)."""
        return self.network.init(key, obs)

    def init_task_params(self) -> Any:
        """The task distribution's initial state (e.g. a curriculum's), or None."""
        return None

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        """The next task distribution from the rollout's per-step stats `[T, B]`."""
        return task_params

    def task_metrics(self, task_params: Any) -> dict[str, jax.Array]:
        """Scalars of the task distribution logged with each update (e.g. the curriculum stage)."""
        return {}


def trace_once(fn: Any, *args: Any) -> tuple[Any, Any]:
    """`fn(*args)` traced once: `(replay, output shapes)`, `replay(*args)` re-binding the traced
    program (cheap, unlike tracing `fn` again: an MJX env step takes seconds), e.g. for a
    `lax.cond` branch whose other branch needs the output shapes."""
    closed, shapes = jax.make_jaxpr(fn, return_shape=True)(*args)
    program = jax_core.jaxpr_as_fun(closed)

    def replay(*call_args: Any) -> Any:
        return jax.tree.unflatten(jax.tree.structure(shapes), program(*jax.tree.leaves(call_args)))

    return replay, shapes


def zeros_like_shapes(shapes: Any) -> Any:
    """Zeros of every `jax.ShapeDtypeStruct` in a tree."""
    return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)


@struct.dataclass
class RunnerState:
    params: Any
    opt_state: Any
    env_state: Any  # leading axis B
    obs: Any  # leading axis B
    task_params: Any
    key: jax.Array
    update: jax.Array  # int32, updates done


class Trainer:
    """PPO for one method; `mesh` (axis "env") shards the env batch over devices."""

    def __init__(self, config: PPOConfig, method: Method, mesh: Mesh | None = None):
        if mesh is not None and config.num_envs % mesh.size:
            raise ValueError(
                f"num_envs={config.num_envs} is not divisible by the {mesh.size} devices of the "
                f"mesh; use a multiple of {mesh.size} (e.g. --num-envs "
                f"{-(-config.num_envs // mesh.size) * mesh.size}) or fewer devices"
            )
        self.config, self.method, self.mesh = config, method, mesh
        self.loss_fn = losses.LOSSES[config.loss]
        # clipping and Adam on one flat vector of every parameter: a few kernels per gradient
        # step instead of a few per leaf (the update loop is launch-bound); the same arithmetic
        # but for the order in which the clipping norm is summed
        self.optimizer = optax.flatten(optax.chain(
            optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.lr, eps=config.adam_eps)
        ))

    def constrain(self, tree: Any, axis: int = 0) -> Any:
        """Shard axis `axis` of every leaf over the mesh: the env axis of the rollout's carry,
        the sample axis of the minibatches (else XLA gathers the shuffled batch onto every device
        and each computes the whole update). A leaf whose axis does not divide is left as is."""
        if self.mesh is None:
            return tree
        sharding = NamedSharding(self.mesh, PartitionSpec(*(None,) * axis, "env"))
        return jax.tree.map(lambda x: x if x.shape[axis] % self.mesh.size
                            else jax.lax.with_sharding_constraint(x, sharding), tree)

    def per_device(self, step_batch: Callable) -> Callable:
        """`step_batch(keys, state, action, task_params)` over the env axis, run by each device on
        its own envs (`shard_map`) on a mesh of several: every op of the env, foreign calls
        included (MuJoCo Warp, which XLA would otherwise gather onto every device), stays where
        its envs are. Unchanged on one device."""
        if self.mesh is None or self.mesh.size == 1:
            return step_batch
        envs = PartitionSpec("env")
        return jax.shard_map(step_batch, mesh=self.mesh, in_specs=(envs, envs, envs, PartitionSpec()),
                             out_specs=envs, check_vma=False)

    def apply(self, params: Any, obs: Any):
        return self.method.network.apply(params, obs)

    def init(self, key: jax.Array) -> RunnerState:
        key_params, key_env, key_run = jax.random.split(key, 3)
        task_params = self.method.init_task_params()
        obs, env_state = rollout.reset_batch(self.method.env, key_env, self.config.num_envs, task_params)
        env_state, obs = self.constrain((env_state, obs))
        params = self.method.init_params(key_params, jax.tree.map(lambda x: x[:1], obs))
        opt_state = self.optimizer.init(params)
        return RunnerState(params, opt_state, env_state, obs, task_params, key_run, jnp.zeros((), jnp.int32))

    def collect(self, runner: RunnerState, key: jax.Array) -> tuple[Any, Any, rollout.Transition]:
        """An update's rollout, `num_steps` steps of the policy in `runner`'s B envs:
        `(env_state, obs, transitions [T, B, ...])` (`rollout.collect`)."""
        cfg = self.config
        return rollout.collect(
            key, runner.params, self.apply, self.method.env, runner.env_state, runner.obs,
            runner.task_params, cfg.num_steps, cfg.gamma, cfg.timeouts_terminal, self.constrain,
            self.per_device,
        )

    def learn(self, params: Any, opt_state: Any, traj: rollout.Transition, last_obs: Any,
              key: jax.Array) -> tuple[Any, Any, dict[str, jax.Array], jax.Array]:
        """An update's PPO step on a collected rollout (`traj [T, B, ...]`, then `last_obs`):
        advantages, then epochs of minibatch gradient steps (stopped early past `target_kl`).
        Returns `(params, opt_state, the last epoch's loss metrics, epochs run: int32)`."""
        cfg = self.config
        # ADVANTAGES (reward GAE; reachability cost for RCO)
        last = self.apply(params, last_obs)
        advantage, target = losses.compute_gae(
            traj.reward, traj.value, traj.done, last.value, cfg.gamma, cfg.gae_lambda
        )
        if cfg.loss == "rco":
            cost_advantage, cost_target = losses.compute_reachability_cost(
                traj.cost, traj.cost_value, traj.done, last.cost_value, cfg.gamma, cfg.gae_lambda
            )
        else:
            cost_advantage = cost_target = jnp.zeros_like(advantage)
        batch = losses.Batch(
            traj.obs, traj.action, traj.log_prob, traj.value, traj.cost_value,
            advantage, target, cost_advantage, cost_target,
        )
        batch = jax.tree.map(lambda x: x.reshape(cfg.batch_size, *x.shape[2:]), batch)

        # EPOCHS OF MINIBATCH UPDATES
        return self._epochs(params, opt_state, batch, key)

    def update(self, runner: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        """One update: `collect`, then `learn`, then the task distribution's next state."""
        key, key_collect, key_epochs = jax.random.split(runner.key, 3)
        env_state, obs, traj = self.collect(runner, key_collect)
        learned = self.learn(runner.params, runner.opt_state, traj, obs, key_epochs)
        return self._advance(runner, key, env_state, obs, traj, *learned)

    def update_seeds_in_turn(self, runners: RunnerState) -> tuple[RunnerState, dict[str, jax.Array]]:
        """`update` over a leading seed axis of `runners`: the seeds collect side by side, then
        learn one after the other (`lax.map`), each running only its own epochs."""
        keys = jax.vmap(lambda k: jax.random.split(k, 3))(runners.key)
        env_state, obs, traj = jax.vmap(self.collect)(runners, keys[:, 1])
        learned = jax.lax.map(lambda args: self.learn(*args),
                              (runners.params, runners.opt_state, traj, obs, keys[:, 2]))
        return jax.vmap(self._advance)(runners, keys[:, 0], env_state, obs, traj, *learned)

    def _advance(self, runner: RunnerState, key: jax.Array, env_state: Any, obs: Any,
                 traj: rollout.Transition, params: Any, opt_state: Any,
                 loss_metrics: dict[str, jax.Array], epochs: jax.Array
                 ) -> tuple[RunnerState, dict[str, jax.Array]]:
        """The runner after an update's rollout and learning, and the update's metrics."""
        task_params = self.method.update_task_params(runner.task_params, traj.stats)
        stats = {k: jnp.sum(v) for k, v in traj.stats.items() if not k.startswith("_")}
        runner = RunnerState(params, opt_state, env_state, obs, task_params, key, runner.update + 1)
        metrics = {**stats, **loss_metrics, "epochs": epochs, "reward": jnp.mean(traj.reward),
                   **self.method.task_metrics(task_params)}
        return runner, metrics

    def _epochs(self, params, opt_state, batch, key):
        cfg, loss_cfg = self.config, self.config.loss_config()

        def minibatch_step(carry, minibatch):
            params, opt_state = carry

            def loss_of(p):
                return self.loss_fn(self.apply(p, minibatch.obs), minibatch, loss_cfg)

            (_, metrics), grads = jax.value_and_grad(loss_of, has_aux=True)(params)
            updates, opt_state = self.optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), metrics

        def epoch(params, opt_state, key_epoch):
            order = jax.random.permutation(key_epoch, cfg.batch_size)
            shuffled = jax.tree.map(
                lambda x: x[order].reshape(cfg.num_minibatches, cfg.minibatch_size, *x.shape[1:]), batch
            )
            shuffled = self.constrain(shuffled, axis=1)  # data-parallel minibatch steps
            (params, opt_state), metrics = jax.lax.scan(minibatch_step, (params, opt_state), shuffled)
            return params, opt_state, jax.tree.map(jnp.mean, metrics)

        keys = jax.random.split(key, cfg.update_epochs)
        epoch, shapes = trace_once(epoch, params, opt_state, keys[0])
        zero_metrics = zeros_like_shapes(shapes[2])

        def cond(carry):
            i, _, _, metrics = carry
            below = True if cfg.target_kl is None else (i == 0) | (metrics["approx_kl"] <= cfg.target_kl)
            return (i < cfg.update_epochs) & below

        def body(carry):
            i, params, opt_state, _ = carry
            params, opt_state, metrics = epoch(params, opt_state, keys[i])
            return i + 1, params, opt_state, metrics

        epochs, params, opt_state, metrics = jax.lax.while_loop(
            cond, body, (jnp.zeros((), jnp.int32), params, opt_state, zero_metrics)
        )
        return params, opt_state, metrics, epochs

    def updates(self, runner: RunnerState, num_updates: int,
                active: jax.Array | None = None, step: Callable | None = None
                ) -> tuple[RunnerState, dict[str, jax.Array]]:
        """`num_updates` updates in one scan; metrics stacked `[num_updates]`.

        `active` (int32 scalar, may be traced; keep it unbatched under `vmap`) runs only the first
        `active` updates and passes the state through the rest (their metrics are zeros), so one
        compiled chunk also serves a shorter last chunk. `step`: the update (default `update`;
        `update_seeds_in_turn` for a runner with a seed axis).
        """
        step = step or self.update
        if active is None:
            return jax.lax.scan(lambda r, _: step(r), runner, None, length=num_updates)

        def body(r, i):
            update, shapes = trace_once(step, r)  # traced once, not again for the shapes
            skipped = zeros_like_shapes(shapes[1])
            return jax.lax.cond(i < active, update, lambda r: (r, skipped), r)

        return jax.lax.scan(body, runner, jnp.arange(num_updates))

    def __call__(self, key: jax.Array) -> tuple[RunnerState, dict[str, jax.Array]]:
        return self.updates(self.init(key), self.config.num_updates)


def make_train(config: PPOConfig, method: Method, mesh: Mesh | None = None) -> Trainer:
    """`train = make_train(config, method)`; `jax.jit(train)(key)` runs the whole training."""
    return Trainer(config, method, mesh)


def env_mesh(devices: list | None = None) -> Mesh:
    """A one-axis mesh named "env" over `devices` (default: `jax.devices()`, every device of
    this process, and after `jax.distributed.initialize` of every process of the job)."""
    import numpy as np

    return Mesh(np.asarray(devices if devices is not None else jax.devices()), ("env",))
