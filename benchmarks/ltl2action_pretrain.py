"""Pretrain LTL2Action's formula encoder on the symbol task (the original's optional LTLBootcamp)
and save it, for training runs to start from (`train_baselines.py --ltl2action-encoder PATH`,
optionally `--ltl2action-freeze-encoder`); `--ltl2action-pretrain-steps N` instead pretrains
inside the training run. The formulas are the ones the method trains on in that world (its
curriculum by default, or `--sampler`).

    python benchmarks/ltl2action_pretrain.py --env LetterLTL0-v0 --steps 10000000 \
        --out /tmp/l2a_encoder_letter.msgpack
(the original's PPO shape, 16 envs x 512 steps; on a GPU `--num-envs 1024 --num-steps 64
--minibatches 16` runs it wider, as benchmarks/rad_pretrain.py does).
On a CPU, a little (to see it learn):
    python benchmarks/ltl2action_pretrain.py --env LetterLTL0-v0 --steps 65536 --num-formulas 64 \
        --out /tmp/l2a_encoder_cpu.msgpack
"""

from __future__ import annotations

import argparse
import sys
import time

import flax
import jax
import numpy as np

from specrl_jax.baselines import experiment, ltl2action
from specrl_jax.baselines.ltl2action import pretrain as ltl2action_pretrain
from specrl_jax.envs.registry import make


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="LetterLTL0-v0", help="the world whose alphabet and formulas")
    parser.add_argument("--steps", type=int, default=10_000_000, help="symbol-task env steps")
    parser.add_argument("--sampler", default=None, help="default: the method's for the world")
    parser.add_argument("--num-formulas", type=int, default=1024, help="draws per sampled stage")
    parser.add_argument("--num-envs", type=int, default=None, help="default: the original's 16")
    parser.add_argument("--num-steps", type=int, default=None, help="default: the original's 512")
    parser.add_argument("--minibatches", type=int, default=None, help="default: 8 (of 1,024)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True, help="the encoder file (.msgpack; a .json beside it)")
    args = parser.parse_args()
    family = experiment.family(args.env)
    world, _ = make(args.env)
    by_stage = ltl2action.training_formulas(world.propositions, family, args.num_formulas,
                                            args.seed, args.sampler)
    formulas = [f for stage in by_stage for f in stage]
    stages = ([len(s) for s in by_stage]
              if ltl2action.check_sampler(family, args.sampler) == "curriculum" else None)
    lines: list[str] = []

    def log(line: str) -> None:
        lines.append(line)
        print(line, flush=True)

    shape = {name: value for name, value in (("num_envs", args.num_envs),
                                             ("num_steps", args.num_steps),
                                             ("num_minibatches", args.minibatches))
             if value is not None}
    start = time.perf_counter()
    encoder = ltl2action.pretrain_encoder(
        np.asarray(world.alphabet), tuple(world.propositions), formulas, stages, family,
        jax.random.key(args.seed), args.steps, log, **shape)
    wall = time.perf_counter() - start
    meta = {"env": args.env, "sampler": ltl2action.check_sampler(family, args.sampler),
            "formulas": len(formulas), "steps": args.steps, "ppo_shape": shape, "wall_s_with_compile": wall,
            "last_progress": lines[-1], "device": str(jax.devices()[0].device_kind),
            "jax": jax.__version__, "flax": flax.__version__, "date": time.strftime("%Y-%m-%d"),
            "command": "python benchmarks/ltl2action_pretrain.py " + " ".join(sys.argv[1:])}
    ltl2action_pretrain.save_encoder(args.out, encoder, meta)
    print(f"saved {args.out} after {wall:.1f}s ({args.steps / wall:,.0f} env-steps/s with compile)")


if __name__ == "__main__":
    main()
