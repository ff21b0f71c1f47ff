"""Where one LetterWorld training run spends its time: compilation, rollout (collect + advantages)
per update, one epoch of minibatch updates, the CNN's forward/backward alone (`nn.Conv` against the
LetterCNN's matmul), and the epochs the KL stop leaves per update. Writes a JSON of the timings.

Example (GPU):
    python benchmarks/train_profile.py --method genz --out /tmp/profile.json
The CNN comparison alone (CPU, one 128-image minibatch):
    python benchmarks/train_profile.py --cnn-only 128 --out /tmp/cnn.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.baselines import experiment, runs
from specrl_jax.baselines.ppo import losses, make_train, rollout
from specrl_jax.baselines.ppo.networks import LetterCNN


def timed(fn, *args, repeats: int = 3) -> tuple[float, float]:
    """(first call incl. compilation, best of `repeats` later calls) in seconds."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - start)
    return first, float(best)


def collect_batch(trainer, runner):
    """One update's rollout and advantages, flattened to the minibatch layout."""
    cfg = trainer.config
    env_state, obs, traj = rollout.collect(
        runner.key, runner.params, trainer.apply, trainer.method.env, runner.env_state, runner.obs,
        runner.task_params, cfg.num_steps, cfg.gamma, cfg.timeouts_terminal,
    )
    last = trainer.apply(runner.params, obs)
    advantage, target = losses.compute_gae(traj.reward, traj.value, traj.done, last.value, cfg.gamma,
                                           cfg.gae_lambda)
    cost_advantage, cost_target = losses.compute_reachability_cost(
        traj.cost, traj.cost_value, traj.done, last.cost_value, cfg.gamma, cfg.gae_lambda
    )
    batch = losses.Batch(traj.obs, traj.action, traj.log_prob, traj.value, traj.cost_value, advantage,
                         target, cost_advantage, cost_target)
    batch = jax.tree.map(lambda x: x.reshape(cfg.batch_size, *x.shape[2:]), batch)
    return runner.replace(env_state=env_state, obs=obs, key=jax.random.split(runner.key)[0]), batch


class LibraryConvCNN(nn.Module):
    """The LetterCNN's architecture with the library convolution (`nn.Conv`, 2x2 VALID): the
    reference for `LetterCNN`'s shifted-view matmul. Same parameter tree, so both run on one set."""

    channels: tuple[int, ...] = (16, 32, 64)

    @nn.compact
    def __call__(self, image: jax.Array) -> jax.Array:
        x = image.astype(jnp.float32)
        for width in self.channels:
            x = nn.relu(nn.Conv(width, (2, 2), padding="VALID")(x))
        return x.reshape(*x.shape[:-3], -1)


def cnn_timings(obs: jax.Array) -> dict[str, float]:
    """Forward + backward (s) on `obs` [N, V, V, C]: `nn.Conv` vs the LetterCNN in use (`Conv2x2`)."""
    cnn = LetterCNN()
    params = cnn.init(jax.random.key(0), obs[:1])
    library = lambda p: LibraryConvCNN(tuple(cnn.channels)).apply(p, obs)
    matmul = lambda p: cnn.apply(p, obs)
    out = {"max_abs_diff": float(jnp.max(jnp.abs(jax.jit(library)(params) - jax.jit(matmul)(params)))),
           "images": int(obs.shape[0])}
    for name, fn in (("nn_conv", library), ("conv2x2_matmul", matmul)):
        @jax.jit
        def loop(p, fn=fn):
            def body(q, _):
                g = jax.grad(lambda r: jnp.sum(jnp.tanh(fn(r))))(q)
                return jax.tree.map(lambda a, b: a - 1e-6 * b, q, g), None
            return jax.lax.scan(body, p, None, length=50)[0]

        out[name] = timed(loop, params)[1] / 50
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="genz", choices=list(experiment.METHODS))
    parser.add_argument("--env", default="LetterLTL0-v0")
    parser.add_argument("--num-envs", type=int, default=None)
    parser.add_argument("--num-steps", type=int, default=None)
    parser.add_argument("--minibatches", type=int, nargs="+", default=[8])
    parser.add_argument("--rollouts", type=int, default=20, help="updates' rollouts per timing")
    parser.add_argument("--epochs", type=int, default=10, help="epochs per epoch timing")
    parser.add_argument("--chunk", type=int, default=10, help="updates per timed training chunk")
    parser.add_argument("--map-bank", type=int, default=65536)
    parser.add_argument("--cnn-only", type=int, default=None, metavar="N",
                        help="only the CNN comparison, on N random reduced LetterWorld images, 3 times")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    if args.cnn_only:
        images = jax.random.choice(jax.random.key(3), jnp.array([0.0, 0.2, 0.5, 1.0]), (args.cnn_only, 7, 7, 1))
        report = {"device": str(jax.devices()[0]), "jax": jax.__version__,
                  "cnn_fwd_bwd_s": [cnn_timings(images) for _ in range(3)]}
        print(json.dumps(report), flush=True)
        Path(args.out).write_text(json.dumps(report, indent=1))
        return

    device = jax.devices()[0]
    overrides = experiment.default_overrides(device.platform)
    for flag, name in (("num_envs", "num_envs"), ("num_steps", "num_steps")):
        if getattr(args, flag) is not None:
            overrides[name] = getattr(args, flag)
    report = {"device": str(device), "jax": jax.__version__, "method": args.method, "shape": overrides}
    key_bank, key_init = jax.random.split(jax.random.key(0))
    _, _, method, config = experiment.build(args.method, args.env, overrides, args.map_bank, key_bank)
    trainer = make_train(config, method)
    runner = jax.jit(trainer.init)(key_init)

    # ROLLOUT: collect + advantages, `rollouts` updates in one scan
    @jax.jit
    def rollouts(runner):
        return jax.lax.scan(lambda r, _: (collect_batch(trainer, r)[0], None), runner, None,
                            length=args.rollouts)[0].obs

    first, best = timed(rollouts, runner)
    report["rollout_s_per_update"] = best / args.rollouts
    report["rollout_compile_s"] = first - best
    runner, batch = jax.jit(lambda r: collect_batch(trainer, r))(runner)

    # EPOCHS: fixed epoch count (no KL stop), per minibatch count
    report["epoch_s"] = {}
    report["grad_s_per_minibatch"] = {}
    for num_mb in args.minibatches:
        cfg = dataclasses.replace(config, update_epochs=args.epochs, target_kl=None, num_minibatches=num_mb)
        epoch_trainer = make_train(cfg, method)
        epochs = jax.jit(lambda p, o, b, k, t=epoch_trainer: t._epochs(p, o, b, k)[0])
        _, best = timed(epochs, runner.params, runner.opt_state, batch, jax.random.key(1))
        report["epoch_s"][num_mb] = best / args.epochs
        minibatch = jax.tree.map(lambda x, n=cfg.minibatch_size: x[:n], batch)
        loss_cfg = cfg.loss_config()

        @jax.jit
        def grads(params, minibatch=minibatch, loss_cfg=loss_cfg, t=epoch_trainer):
            def body(p, _):
                g = jax.grad(lambda q: t.loss_fn(t.apply(q, minibatch.obs), minibatch, loss_cfg)[0])(p)
                return jax.tree.map(lambda a, b: a - 1e-6 * b, p, g), None
            return jax.lax.scan(body, params, None, length=50)[0]

        _, best = timed(grads, runner.params)
        report["grad_s_per_minibatch"][num_mb] = best / 50
        if args.method == "genz":
            report[f"cnn_fwd_bwd_s_{num_mb}"] = cnn_timings(minibatch.obs)
        print(json.dumps(report), flush=True)

    # TRAINING CHUNKS: the trainer's own update (KL stop) exactly as `runs.train_in_run_dir` calls
    # it for one seed: unbatched inside a seed axis of 1, with the `active` count of a partly idle chunk
    updates = jax.jit(runs.seed_batched(trainer, 1), static_argnums=1, donate_argnums=0)
    seeds = jax.tree.map(lambda x: x[None], runner)
    active = jnp.int32(args.chunk)
    start = time.perf_counter()
    compiled = updates.lower(seeds, args.chunk, active).compile()
    report["update_chunk_compile_s"] = time.perf_counter() - start
    for i in range(3):
        start = time.perf_counter()
        seeds, metrics = compiled(seeds, active)
        epochs = np.asarray(jax.device_get(metrics["epochs"]))
        report[f"chunk{i}_s_per_update"] = (time.perf_counter() - start) / args.chunk
        report[f"chunk{i}_mean_epochs"] = float(epochs.mean())
    print(json.dumps(report), flush=True)
    Path(args.out).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
