"""Evaluation speed on LetterWorld: every finite-horizon LetterWorld spec x seeds x episodes.

Times one compiled `evaluate` call (all (seed, spec, episode) lanes, horizon 75) for the random
policy and the optimal planner, after compilation, and reports the compile time separately.

    python benchmarks/eval_letter.py --save-specs /tmp/letter_specs.npz   # compile specs (Spot)
    python benchmarks/eval_letter.py --load-specs /tmp/letter_specs.npz --out results.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax import automata, specs
from specrl_jax.eval.evaluate import make_evaluator
from specrl_jax.eval.metrics import EpisodeTable, per_seed_metrics
from specrl_jax.eval.planner import oracle_policy
from specrl_jax.tasks.policy import random_policy
from specrl_jax.eval.report import versions
from specrl_jax.tasks import TaskEnv

ENV_ID = "LetterLTL0-v0"


PAPER_PREFIXES = ("letter/finite/", "letter/complexity_paper/", "deepltl/letter/", "genz/letter/")
ALL_PREFIXES = ("letter/", "deepltl/letter/", "genz/letter/")


def finite_letter_formulas(prefixes: tuple[str, ...]) -> list[str]:
    """Every distinct formula of the finite-horizon suites under `prefixes`, in suite order."""
    names = [n for n in specs.list_suites()
             if n.startswith(prefixes) and specs.suite_info(n).is_finite]
    return list(dict.fromkeys(f for n in names for f in specs.suite(n)))


def load_specs(args: argparse.Namespace, env) -> tuple[automata.CompiledSpec, int, list[str]]:
    """The stacked specs, their number, and the formulas that failed to compile."""
    if args.load_specs:
        with np.load(args.load_specs) as data:
            stacked = automata.CompiledSpec(**{k: jnp.asarray(data[k]) for k in data.files})
        return stacked, int(stacked.delta.shape[0]), []
    prefixes = ALL_PREFIXES if args.suites == "all" else PAPER_PREFIXES
    compiled, failed = [], []
    for formula in finite_letter_formulas(prefixes)[: args.limit]:
        try:
            compiled.append(automata.compile_spec(formula, env.propositions, alphabet=env.alphabet))
        except ValueError:
            failed.append(formula)
    stacked = automata.stack(compiled)
    if args.save_specs:
        np.savez_compressed(args.save_specs, **{k: np.asarray(v) for k, v in
                                                vars(stacked).items()})
    return stacked, len(compiled), failed


def obs_reading_policy(env):
    """Random actions shifted by a checksum of the observation: neither the random policy nor
    the planner reads `obs`, so XLA drops its construction; this one forces it, as a network
    policy would."""
    sample = random_policy(env)

    def policy(policy_params, obs, task_state, key):
        checksum = sum(jnp.sum(x.astype(jnp.int32)) for x in jax.tree.leaves(obs))
        return (sample(policy_params, obs, task_state, key) + checksum) % env.action_space.n

    return policy


def time_policy(name, policy, task, params, args) -> dict:
    seeds = jnp.arange(1, args.seeds + 1, dtype=jnp.uint32)
    evaluator = make_evaluator(policy, task, params, args.episodes,
                               sequential_seeds=args.sequential_seeds)
    start = time.perf_counter()
    compiled = evaluator.lower(None, seeds).compile()
    compile_s = time.perf_counter() - start
    runs, table = [], None
    for _ in range(args.repeats):
        start = time.perf_counter()
        table = jax.block_until_ready(compiled(None, seeds))
        runs.append(time.perf_counter() - start)
    metrics = per_seed_metrics(EpisodeTable(*(np.asarray(x) for x in table)))
    episodes = args.seeds * task.num_specs * args.episodes
    return {
        "policy": name,
        "compile_s": round(compile_s, 2),
        "run_s_min": round(min(runs), 3),
        "run_s_median": round(statistics.median(runs), 3),
        "episodes": episodes,
        "lane_steps_per_s": round(episodes * int(params.max_steps) / min(runs)),
        "eta_s": round(float(metrics["eta_s"].mean()), 4),
        "eta_v": round(float(metrics["eta_v"].mean()), 4),
        "mu": round(float(np.nanmean(metrics["mu"])), 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--limit", type=int, default=None, help="only the first N formulas")
    parser.add_argument("--suites", choices=("paper", "all"), default="paper",
                        help="the paper's LetterWorld suites, or every finite letter suite")
    parser.add_argument("--policies", default="random,oracle")
    parser.add_argument("--sequential-seeds", action="store_true",
                        help="lax.map over seeds instead of vmap (5x less memory)")
    parser.add_argument("--save-specs", default=None)
    parser.add_argument("--load-specs", default=None)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    env, params = specrl_jax.make(ENV_ID)
    stacked, count, failed = load_specs(args, env)
    task = TaskEnv(env, stacked)
    policies = {"random": random_policy(env), "oracle": oracle_policy(env),
                "obs-reading": obs_reading_policy(env)}
    record = {
        "env": ENV_ID, "specs": count, "failed_to_compile": failed, "seeds": args.seeds, "episodes_per_seed": args.episodes,
        "horizon": int(params.max_steps), "padded_shapes": {
            "S": int(stacked.delta.shape[1]), "C": int(stacked.seq_pair.shape[2]),
            "L": int(stacked.seq_pair.shape[3])},
        "versions": versions(), "results": [],
    }
    for name in args.policies.split(","):
        record["results"].append(time_policy(name, policies[name], task, params, args))
        print(json.dumps(record["results"][-1]), flush=True)
    print(json.dumps({k: v for k, v in record.items() if k != "results"}))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(record, f, indent=1)


if __name__ == "__main__":
    main()
