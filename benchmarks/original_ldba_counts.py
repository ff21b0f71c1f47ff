"""Accepting visits on our Spot automata vs the original's Owl LDBAs, on the same label words.

For every suite with original automata (`specs/data/original_ldbas.json`), both counts are taken
on fixed label sequences:

* `safe_walk`: sticky random labels (kept with probability `--stay`, else drawn uniformly) among
  those that do not violate our automaton, at the suite's infinite horizon (10x the finite one:
  LetterWorld 750, Zone and multi-agent Zone 10,000, Arm 2,000 steps). Where our state has an
  epsilon edge whose target accepts the drawn label, ours jumps first (an epsilon step, no
  label), as a DeepLTL agent on our automaton would.
* `oracle` (LetterWorld only): episodes of the LetterWorld planner (`eval.oracle_policy`), which
  walks to the nearest accepting transition of our automaton, 750 steps, fresh maps.

Ours: `automata.step` (`accepted`). Original: `eval.original_ldba.step` under both rules.
Writes benchmarks/results/original_ldba_counts.json and prints one row per suite.

    python benchmarks/original_ldba_counts.py [--words 64] [--stay 0.9]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax import automata, specs
from specrl_jax.automata import product, zero_or_one
from specrl_jax.eval import original_ldba as ol
from specrl_jax.eval.evaluate import record_episodes
from specrl_jax.eval.planner import oracle_policy
from specrl_jax.tasks import TaskEnv

SUITES = ("letter/infinite/rsp", "letter/infinite/rec", "zone/infinite/rsp", "zone/infinite/rec",
          "zone/infinite/per", "arm_grippers/infinite/rsp", "arm_grippers/infinite/rec",
          "arm_grippers/infinite/per", "multi_agent_zone/infinite/rsp",
          "multi_agent_zone/infinite/rec", "multi_agent_zone/infinite/per")
HORIZON = {"letter": 750, "zone": 10_000, "arm": 2_000, "multi_agent_zone": 10_000}


def world(name: str) -> tuple[tuple[str, ...], np.ndarray]:
    info = specs.suite_info(name)
    if info.alphabet == "per_agent_zero_or_one":
        return info.propositions, product(zero_or_one(4), zero_or_one(4))
    return info.propositions, zero_or_one(len(info.propositions))


def safe_walk_counts(spec, ldba, key, horizon: int, stay: float):
    """(ours, original 'policy', original 'hindsight', ours jumped) on one sticky safe walk."""
    alphabet = spec.alphabet

    def body(carry, key):
        q, prev, ours, policy, hindsight, jumped = carry
        key_stay, key_draw = jax.random.split(key)
        safe = ~spec.violation[spec.delta[q]]
        eps = spec.epsilon[q, 0]
        jump_safe = (eps >= 0) & ~spec.violation[spec.delta[jnp.maximum(eps, 0)]]
        safe = safe | jump_safe
        draw = jax.random.categorical(key_draw, jnp.where(safe, 0.0, -jnp.inf))
        keep = (jax.random.uniform(key_stay) < stay) & safe[prev]
        symbol = jnp.where(keep | ~safe.any(), prev, draw)
        # our epsilon step first where the jump target accepts the label (or only it is safe)
        jump = (eps >= 0) & (spec.accepting[jnp.maximum(eps, 0), symbol]
                             | spec.violation[spec.delta[q, symbol]])
        q1 = jnp.where(jump, automata.step(spec, q, alphabet[symbol], True)[0], q)
        jumped_policy, _ = ol.step(ldba, policy, symbol, True, rule="policy")
        policy = jax.tree.map(lambda a, b: jnp.where(jump, a, b), jumped_policy, policy)
        q2, acc, _, _ = automata.step(spec, q1, alphabet[symbol], False)
        policy, _ = ol.step(ldba, policy, symbol, False, rule="policy")
        hindsight, _ = ol.step(ldba, hindsight, symbol, False, rule="hindsight")
        return (q2, symbol, ours + acc, policy, hindsight, jumped | jump), None

    start = (spec.init, jnp.int32(0), jnp.int32(0), ol.init(ldba), ol.init(ldba),
             jnp.bool_(False))
    (q, _, ours, policy, hindsight, jumped), _ = jax.lax.scan(
        body, start, jax.random.split(key, horizon))
    return ours, policy.visits, hindsight.visits, jumped, spec.violation[q]


def oracle_counts(name: str, index: int, words: int, seed: int):
    """(ours, original 'policy', original 'hindsight') on planner episodes in LetterWorld."""
    env, params = specrl_jax.make("LetterLTL0-v0")
    params = params.replace(max_steps=HORIZON["letter"])  # one episode per word, no auto-reset
    formula = specs.suite(name)[index]
    spec = automata.compile_spec(formula, env.propositions, alphabet=np.asarray(env.alphabet))
    bank = automata.stack([spec])
    ldba = jax.tree.map(lambda x: x[index], ol.suite_ldbas(name, env))
    keys = jax.random.split(jax.random.key(seed), words)
    states, alive = record_episodes(oracle_policy(env), TaskEnv(env, bank), params, keys,
                                    jnp.zeros(words, jnp.int32), horizon=HORIZON["letter"])

    def original(props, alive, rule):
        def body(tracker, x):
            label, live = x
            new, _ = ol.step(ldba, tracker, label, False, rule=rule)
            return jax.tree.map(lambda a, b: jnp.where(live, a, b), new, tracker), None
        tracker, _ = jax.lax.scan(body, ol.init(ldba), (props[1:], alive[1:]))
        return tracker.visits

    props = states.propositions
    policy = jax.jit(jax.vmap(lambda p, a: original(p, a, "policy")))(props, alive)
    hindsight = jax.jit(jax.vmap(lambda p, a: original(p, a, "hindsight")))(props, alive)
    ours = jnp.where(alive, states.num_accepting, 0).max(axis=1)
    return np.asarray(ours), np.asarray(policy), np.asarray(hindsight)


def summary(ours, orig) -> dict:
    ours, orig = np.asarray(ours, float), np.asarray(orig, float)
    diff = orig - ours
    return {"ours_mean": ours.mean(), "original_mean": orig.mean(),
            "diff_mean": diff.mean(), "diff_min": diff.min(), "diff_max": diff.max(),
            "equal_frac": float((diff == 0).mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--words", type=int, default=64)
    parser.add_argument("--stay", type=float, default=0.9)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--suites", nargs="*", default=list(SUITES))
    parser.add_argument("--out", default="benchmarks/results/original_ldba_counts.json")
    args = parser.parse_args()
    start = time.perf_counter()
    rows = {}
    for name in args.suites:
        props, alphabet = world(name)
        ldbas = ol.suite_ldbas(name, type("W", (), {"propositions": props,
                                                    "alphabet": alphabet})())
        horizon = HORIZON[specs.suite_info(name).env_family]
        per_formula = []
        for i, formula in enumerate(specs.suite(name)):
            spec = automata.compile_spec(formula, props, alphabet=alphabet)
            ldba = jax.tree.map(lambda x, i=i: x[i], ldbas)
            keys = jax.random.split(jax.random.fold_in(jax.random.key(args.seed), i), args.words)
            run = jax.jit(jax.vmap(lambda k, spec=spec, ldba=ldba: safe_walk_counts(
                spec, ldba, k, horizon, args.stay)))
            ours, policy, hindsight, jumped, violated = (np.asarray(x) for x in run(keys))
            entry = {"formula": formula, "horizon": horizon, "words": args.words,
                     "our_states": int(spec.num_states),
                     "original_states": int(np.asarray(ldba.delta).shape[0]),
                     "our_violated_frac": float(violated.mean()),
                     "our_jump_frac": float(jumped.mean()),
                     "safe_walk_policy": summary(ours, policy),
                     "safe_walk_hindsight": summary(ours, hindsight)}
            if name.startswith("letter/"):
                o_ours, o_policy, o_hind = oracle_counts(name, i, args.words, args.seed)
                entry["oracle_policy"] = summary(o_ours, o_policy)
                entry["oracle_hindsight"] = summary(o_ours, o_hind)
            per_formula.append(entry)
            s = entry["safe_walk_policy"]
            line = (f"{name} #{i}: states ours {entry['our_states']} / original "
                    f"{entry['original_states']}; safe walk ours {s['ours_mean']:.1f} original "
                    f"{s['original_mean']:.1f} (diff {s['diff_min']:.0f}..{s['diff_max']:.0f}, "
                    f"equal {s['equal_frac']:.2f}; hindsight "
                    f"{entry['safe_walk_hindsight']['original_mean']:.1f})")
            if "oracle_policy" in entry:
                o = entry["oracle_policy"]
                line += (f"; oracle ours {o['ours_mean']:.1f} original {o['original_mean']:.1f} "
                         f"(diff {o['diff_min']:.0f}..{o['diff_max']:.0f})")
            print(line, flush=True)
        rows[name] = per_formula
    meta = {"command": "python benchmarks/original_ldba_counts.py "
                       f"--words {args.words} --stay {args.stay} --seed {args.seed}"
                       + ("" if list(args.suites) == list(SUITES)
                          else " --suites " + " ".join(args.suites)),
            "jax": jax.__version__, "device": str(jax.devices()[0]),
            "platform": platform.platform(), "date": time.strftime("%Y-%m-%d"),
            "seconds": round(time.perf_counter() - start, 1)}
    path = pathlib.Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"meta": meta, "suites": rows}, indent=1, default=float))
    print(f"wrote {path} in {meta['seconds']} s")


if __name__ == "__main__":
    main()
