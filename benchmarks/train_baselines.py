"""Reproduce the baselines (GenZ-LTL, DeepLTL, LTL2Action, GCRL-LTL) on any single-agent world.

Train (seeds side by side) through the task loop, evaluate on the paper's suites, write the
results JSON, Markdown tables, curves and timings.

Example (GPU, the full protocol):
    python benchmarks/train_baselines.py --env LetterLTL0-v0 --methods genz deepltl --seeds 5 \
        --total-steps 15000000 --episodes 100 --out /tmp/letter
    python benchmarks/train_baselines.py --env PointLTL0-v0 --suites zone/finite/ind --out /tmp/zone
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax

from specrl_jax.baselines import experiment, ltl2action, rad
from specrl_jax.cli import env_option
from specrl_jax.eval import report

COMPLEXITY = tuple(
    f"letter/complexity_paper/{kind}/seq{n}_disj{d}"
    for kind in ("reach_only", "reach_avoid") for n in (2, 4) for d in (0, 1)
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=["genz", "deepltl"], choices=list(experiment.METHODS))
    parser.add_argument("--env", default="LetterLTL0-v0")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="base key of the training runs and map bank")
    parser.add_argument("--total-steps", type=int, default=15_000_000)
    parser.add_argument("--num-envs", type=int, default=None)
    parser.add_argument("--num-steps", type=int, default=None)
    parser.add_argument("--minibatches", type=int, default=None)
    parser.add_argument("--epochs", type=int, default=None, help="max epochs per update")
    parser.add_argument("--map-bank", type=int, default=65536)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--chunk", type=int, default=20, help="updates per progress line / checkpoint")
    parser.add_argument("--no-eval", action="store_true")
    parser.add_argument("--load", nargs="*", default=[], metavar="METHOD=PATH",
                        help="evaluate parameters saved by an earlier run instead of training")
    parser.add_argument("--max-wall", type=float, default=None, help="training seconds per method")
    parser.add_argument("--stochastic-too", action="store_true",
                        help="also evaluate with the other action mode (diagnostic)")
    parser.add_argument("--complexity", action="store_true", help="also the paper's complexity grid")
    parser.add_argument("--no-threshold-too", action="store_true",
                        help="DeepLTL: also evaluate without the 0.4 value-threshold avoid augmentation")
    parser.add_argument("--suites", nargs="+", default=None, help="default: the world's paper suites")
    parser.add_argument("--env-option", type=env_option, action="append", default=[], metavar="KEY=VALUE",
                        help="an override of the world passed to make(), e.g. image_size=64 (repeatable)")
    parser.add_argument("--ltl2action-sampler", default=None, metavar="NAME",
                        help="LTL2Action's training formulas: 'curriculum' (the world's DeepLTL "
                             "curriculum) or an original sampler such as Until_1_3_1_2; default "
                             "ltl2action.SAMPLERS")
    parser.add_argument("--ltl2action-pretrain-steps", type=int, default=0, metavar="N",
                        help="LTL2Action: pretrain the formula encoder on the symbol task for N "
                             "steps before PPO (the original's LTLBootcamp; 0: none, its default)")
    parser.add_argument("--ltl2action-encoder", default=None, metavar="PATH",
                        help="LTL2Action: start the formula encoder from this file "
                             "(benchmarks/ltl2action_pretrain.py)")
    parser.add_argument("--ltl2action-freeze-encoder", action="store_true",
                        help="LTL2Action: keep the formula encoder fixed (the original's --freeze-ltl)")
    parser.add_argument("--rad-sampler", default=None, choices=["rad", "curriculum"],
                        help="RAD-Embeddings' training tasks: 'rad' (the original's RAD sampler) "
                             "or 'curriculum' (the world's DeepLTL curriculum as DFAs); default "
                             "rad.SAMPLERS")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    env_options = dict(args.env_option)
    method_options = {}  # per method: make_method's options for training, loading and evaluation
    for method, module, sampler in (("ltl2action", ltl2action, args.ltl2action_sampler),
                                    ("rad", rad, args.rad_sampler)):
        if sampler is not None:
            module.check_sampler(experiment.family(args.env), sampler)  # fail before any work
            method_options[method] = {"sampler": sampler}
    encoder_options = {"pretrain_steps": args.ltl2action_pretrain_steps,
                       "encoder": args.ltl2action_encoder,
                       "freeze_encoder": args.ltl2action_freeze_encoder}
    encoder_options = {k: v for k, v in encoder_options.items() if v}
    if encoder_options:
        method_options["ltl2action"] = {**method_options.get("ltl2action", {}), **encoder_options}

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    device = jax.devices()[0]
    world_family = experiment.family(args.env)
    overrides = experiment.default_overrides(device.platform, args.total_steps, world_family)
    for flag, name in (("num_envs", "num_envs"), ("num_steps", "num_steps"),
                       ("minibatches", "num_minibatches"), ("epochs", "update_epochs")):
        if getattr(args, flag) is not None:
            overrides[name] = getattr(args, flag)
    suites = tuple(args.suites or experiment.suites_for(args.env)) + (COMPLEXITY if args.complexity else ())
    results, summaries = [], {}
    loads = dict(item.split("=", 1) for item in args.load)
    for method in args.methods:
        options = method_options.get(method)
        if method in loads:
            params = experiment.load_params(method, args.env, loads[method], args.seeds,
                                            env_options=env_options, method_options=options)
            summary = summaries[method] = {"loaded_from": loads[method]}
        else:
            params, summary = experiment.train(
                method, args.env, out / method, overrides, args.seeds, seed=args.seed, map_bank=args.map_bank,
                chunk_updates=args.chunk, max_wall_s=args.max_wall, env_options=env_options,
                method_options=options,
            )
            summaries[method] = summary
            print(json.dumps(summary["time_to_success"]), flush=True)
        if not args.no_eval:
            start = time.perf_counter()
            results += experiment.evaluate(method, args.env, params, suites, args.episodes,
                                           env_options=env_options, method_options=options)
            if args.stochastic_too:
                # the reference's action mode (experiment.make_policy): GenZ-LTL's and every
                # method's on ZoneEnv deterministic; DeepLTL's and GCRL-LTL's on LetterWorld sampled
                reference_mode = method == "genz" or world_family != "letter"
                label = experiment.METHOD_NAMES[method] + (" (sampled)" if reference_mode else " (mode)")
                results += experiment.evaluate(method, args.env, params, suites[:2], args.episodes,
                                               deterministic=not reference_mode, label=label,
                                               env_options=env_options, method_options=options)
            if args.no_threshold_too and method == "deepltl":
                results += experiment.evaluate(method, args.env, params, suites, args.episodes,
                                               label="DeepLTL (no threshold)", value_threshold=None,
                                               env_options=env_options, method_options=options)
            summary["eval_wall_s"] = time.perf_counter() - start
    config = {"args": vars(args), "device": str(device), "training": summaries}
    (out / "training.json").write_text(json.dumps(config, indent=1, default=str))
    if results:
        report.write_json(out / "results.json", results, config)
        tables = report.markdown_tables(results)
        (out / "tables.md").write_text(tables)
        print(tables, flush=True)
        report.plot_complexity(results, out / "complexity.png")


if __name__ == "__main__":
    main()
