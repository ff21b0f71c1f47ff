"""Pretrain RAD-Embeddings' encoder on the symbol task (through the shared PPO) and measure
env-steps/s; write the encoder of each world family to
`specrl_jax/baselines/data/rad_encoder_<family>.msgpack` (or --params-dir) with a JSON beside it.

Regenerate the shipped encoders (one H100, about 4 minutes for both families; then copy the
four rad_encoder_* files from --params-dir into specrl_jax/baselines/data/):
    python benchmarks/rad_pretrain.py --families letter zone --total-steps 10000000 \
        --num-envs 1024 --num-steps 64 --minibatches 16 --bank-size 4096 --max-wall 90 \
        --params-dir /tmp/rad_encoders --out /tmp/rad_pretrain_h100.json
After training, each family reports how the encoder's packed layout fitted one more rollout of
the final policy and its minibatches (batches that do not fit are encoded padded: same numbers,
slower) and how long that rollout took.
On a CPU, a little (to see it learn):
    python benchmarks/rad_pretrain.py --families letter --total-steps 40960 --num-envs 16 \
        --num-steps 128 --minibatches 2 --bank-size 1024 --out /tmp/rad_pretrain_cpu.json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import flax
import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax.baselines.rad import encoder as rad_encoder, rad_pretrain
from specrl_jax.baselines.ppo import make_train, rollout
from specrl_jax.envs.registry import make

#: the world whose alphabet each family's encoder reads
REFERENCE_ENV = {"letter": "LetterLTL0-v0", "zone": "PointLTL0-v0"}


def pretrain_family(family: str, args: argparse.Namespace) -> dict:
    world, _ = make(REFERENCE_ENV[family])
    start = time.perf_counter()
    method = rad_pretrain.make_pretrain(np.asarray(world.alphabet), tuple(world.propositions),
                                        family, args.bank_size, args.seed)
    setup = time.perf_counter() - start
    overrides = {"total_timesteps": args.total_steps}
    for name, value in (("num_envs", args.num_envs), ("num_steps", args.num_steps),
                        ("num_minibatches", args.minibatches), ("update_epochs", args.epochs)):
        if value is not None:
            overrides[name] = value
    cfg = rad_pretrain.pretrain_config(**overrides)
    trainer = make_train(cfg, method)
    runner = jax.jit(trainer.init)(jax.random.key(args.seed))
    chunk = jax.jit(lambda r: trainer.updates(r, args.chunk))
    rows, done, train_wall, compile_wall = [], 0, 0.0, None
    print(f"{family}: bank of {args.bank_size} conjunctions (graphs of "
          f"{method.network.banks.graphs.num_nodes} nodes) in {setup:.1f}s; "
          f"{cfg.num_envs} envs x {cfg.num_steps} steps, minibatch {cfg.minibatch_size}")
    print(f"{'updates':>8} {'env steps':>11} {'success':>8} {'violation':>9} {'steps/s':>9}")
    while done < cfg.num_updates:
        start = time.perf_counter()
        runner, metrics = jax.block_until_ready(chunk(runner))
        wall = time.perf_counter() - start
        if compile_wall is None:
            compile_wall = wall  # the first chunk includes compilation
        else:
            train_wall += wall
        done += args.chunk
        m = jax.tree.map(lambda x: float(np.sum(x)), metrics)
        episodes = max(m["episodes"], 1.0)
        steps = args.chunk * cfg.batch_size
        row = {"updates": done, "env_steps": done * cfg.batch_size,
               "success_rate": m["successes"] / episodes,
               "violation_rate": m["violations"] / episodes, "steps_per_s": steps / wall,
               "wall_s": wall}
        rows.append(row)
        print(f"{done:>8} {row['env_steps']:>11,} {row['success_rate']:>8.3f} "
              f"{row['violation_rate']:>9.3f} {row['steps_per_s']:>9,.0f}")
        if args.max_wall is not None and train_wall + compile_wall > args.max_wall:
            break
    timed = rows[1:] or rows
    steps_per_s = sum(args.chunk * cfg.batch_size for _ in timed) / sum(r["wall_s"] for r in timed)
    meta = {
        "family": family, "alphabet_env": REFERENCE_ENV[family],
        "num_symbols": int(world.alphabet.shape[0]), "env_steps": rows[-1]["env_steps"],
        "final_success_rate": rows[-1]["success_rate"],
        "final_violation_rate": rows[-1]["violation_rate"], "bank_size": args.bank_size,
        "max_graph_nodes": rad_pretrain.MAX_GRAPH_NODES, "seed": args.seed,
        "ppo": {k: getattr(cfg, k) for k in ("num_envs", "num_steps", "num_minibatches",
                                             "update_epochs", "lr", "gamma", "gae_lambda",
                                             "clip_eps", "ent_coef")},
        "device": str(jax.devices()[0].device_kind), "jax": jax.__version__,
        "flax": flax.__version__, "date": time.strftime("%Y-%m-%d"),
        "command": "python benchmarks/rad_pretrain.py " + " ".join(args.argv),
    }
    params_dir = Path(args.params_dir) if args.params_dir else rad_pretrain.DATA_DIR
    rad_pretrain.save_encoder(params_dir / f"rad_encoder_{family}.msgpack",
                              rad_pretrain.encoder_params(runner.params), meta)
    packing = packing_check(trainer, runner, args.seed)
    print(f"{family}: packed encoding fits {packing['rollout_fit']:.0%} of a rollout's steps "
          f"(load up to {packing['rollout_max_load']}) and {packing['minibatch_fit']:.0%} of its "
          f"minibatches (load up to {packing['minibatch_max_load']}; the rest run padded); "
          f"a rollout takes {packing['rollout_s']:.3f}s of the "
          f"{cfg.batch_size / steps_per_s:.3f}s of an update")
    return {**meta, "setup_s": setup, "compile_and_first_chunk_s": compile_wall,
            "steps_per_s_after_compile": steps_per_s, "packing": packing, "rows": rows}


def packing_check(trainer, runner, seed: int) -> dict:
    """How the encoder's packed layout (`rad_encoder.pack_rows`) fits one more rollout of the
    final policy, per step (the envs' graphs) and per minibatch of a shuffle of it as the update
    draws them, and how long a rollout takes (`rollout_s`, second call). Load: the largest,
    over blocks b, of (nodes of blocks >= b) / (rows of blocks >= b); a batch fits (is encoded
    packed) when its load is at most 1."""
    cfg, banks = trainer.config, trainer.method.network.banks

    def load(obs):
        graph = banks.graph(obs)
        sizes = rad_encoder.block_sizes(banks.packing, *graph.neighbours.shape)
        if sizes is None:  # batches this small are always encoded padded
            return jnp.full((len(banks.packing),), jnp.inf)
        blocks = rad_encoder.node_blocks(graph).reshape(-1, 1)
        counts = jnp.sum(blocks == jnp.arange(len(sizes)), axis=0)
        return jnp.cumsum(counts[::-1])[::-1] / np.cumsum(sizes[::-1])[::-1]

    @jax.jit
    def check(runner):
        _, _, traj = rollout.collect(runner.key, runner.params, trainer.apply,
                                     trainer.method.env, runner.env_state, runner.obs,
                                     runner.task_params, cfg.num_steps, cfg.gamma,
                                     cfg.timeouts_terminal)
        flat = jax.tree.map(lambda x: x.reshape(cfg.batch_size, *x.shape[2:]), traj.obs)
        order = jax.random.permutation(jax.random.key(seed), cfg.batch_size)
        minibatches = jax.tree.map(
            lambda x: x[order].reshape(cfg.num_minibatches, cfg.minibatch_size, *x.shape[1:]),
            flat)
        return jax.lax.map(load, traj.obs), jax.lax.map(load, minibatches)

    jax.block_until_ready(check(runner))
    start = time.perf_counter()
    batches = jax.block_until_ready(check(runner))
    out = {"rollout_s": time.perf_counter() - start}  # the collect, and a little for the loads
    for name, loads in zip(("rollout", "minibatch"), batches):
        loads = np.asarray(loads)  # [batches, blocks]
        out[f"{name}_fit"] = float(np.mean(loads.max(axis=1) <= 1))
        out[f"{name}_max_load"] = round(float(loads.max()), 3)
        out[f"{name}_max_load_per_block"] = [round(float(x), 3) for x in loads.max(axis=0)]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", nargs="+", default=["letter", "zone"],
                        choices=sorted(REFERENCE_ENV))
    parser.add_argument("--total-steps", type=int, default=10_000_000, help="per family")
    parser.add_argument("--num-envs", type=int, default=None)
    parser.add_argument("--num-steps", type=int, default=None)
    parser.add_argument("--minibatches", type=int, default=None)
    parser.add_argument("--epochs", type=int, default=None)
    parser.add_argument("--bank-size", type=int, default=8192)
    parser.add_argument("--chunk", type=int, default=10, help="updates per progress line")
    parser.add_argument("--max-wall", type=float, default=None,
                        help="stop a family after this many seconds (compile included)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--params-dir", default=None, help="default: the package's data dir")
    parser.add_argument("--out", required=True, help="results JSON")
    args = parser.parse_args()
    import sys

    args.argv = sys.argv[1:]
    results = {"platform": platform.platform(), "device": str(jax.devices()[0].device_kind),
               "jax": jax.__version__, "families": {}}
    for family in args.families:
        results["families"][family] = pretrain_family(family, args)
        Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"{'family':>8} {'env steps':>11} {'steps/s':>9} {'success':>8} {'violation':>9}")
    for family, r in results["families"].items():
        print(f"{family:>8} {r['env_steps']:>11,} {r['steps_per_s_after_compile']:>9,.0f} "
              f"{r['final_success_rate']:>8.3f} {r['final_violation_rate']:>9.3f}")


if __name__ == "__main__":
    main()
