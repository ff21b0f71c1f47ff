"""Compile every formula of the paper's spec tables: cold (empty disk cache) and from the cache.

Also reports the bytes of each compiled LetterWorld spec, and with --gpu-step the cost of the
automaton step inside a LetterWorld step at a large batch, next to a table-free consumer of the
label (what any extra per-env kernel costs), with the kernels per loop iteration.

    python benchmarks/automata_compile.py [--gpu-step --batch 65536 --unroll 1 2]
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
COLORS = ("blue", "green", "magenta", "yellow")


def paper_yaml() -> str:
    for path in (os.path.join(HERE, "..", "specrl_jax", "specs", "data", "paper_specs.yaml"),
                 os.path.join(HERE, "..", "..", "shared", "reference", "paper_specs.yaml")):
        if os.path.exists(path):
            return path
    raise FileNotFoundError("paper_specs.yaml not found")


def _flatten(node) -> list[str]:
    if isinstance(node, list):
        return list(node)
    return [f for value in node.values() for f in _flatten(value)]


def paper_cases():
    """(group, formulas, propositions, alphabet) for every table of the paper."""
    from specrl_jax.automata import all_subsets, product, zero_or_one

    with open(paper_yaml()) as f:
        data = yaml.safe_load(f)
    letters = tuple("abcdefghijkl")
    arm = tuple(f"arm_{c}" for c in COLORS) + tuple(f"grippers_{c}" for c in COLORS)
    agents = tuple(f"{c}_{i}" for i in range(3) for c in COLORS)
    groups = {
        "letter": (letters, zero_or_one(12)),
        "letter_complexity": (letters, zero_or_one(12)),
        "zone": (COLORS, zero_or_one(4)),
        "arm_grippers": (COLORS, zero_or_one(4)),
        "arm_grippers_arm": (arm, all_subsets(8)),
        "multi_agent_zone": (agents, product(*[zero_or_one(4)] * 3)),
    }
    return [(g, _flatten(data[g]), props, alpha) for g, (props, alpha) in groups.items()]


def compile_all() -> dict[str, float]:
    from specrl_jax.automata import compile_spec

    out, sizes = {}, []
    t0 = time.perf_counter()
    for group, formulas, props, alphabet in paper_cases():
        for formula in formulas:
            spec = compile_spec(formula, props, alphabet)
            if group.startswith("letter"):
                sizes.append(spec.nbytes)
    out["seconds"] = time.perf_counter() - t0
    out["count"] = sum(len(c[1]) for c in paper_cases())
    out["letter_max_bytes"] = max(sizes)
    out["letter_mean_bytes"] = float(np.mean(sizes))
    out["letter_min_bytes"] = min(sizes)
    out["letter_count"] = len(sizes)
    return out


def child(_args) -> None:
    import specrl_jax  # noqa: F401  (import cost is not part of the compile figure)

    res = compile_all()
    print(f"{res['seconds']:.3f} {res['count']} {res['letter_max_bytes']} "
          f"{res['letter_mean_bytes']:.0f} {res['letter_min_bytes']} {res['letter_count']}")


def scan_body_kernels(hlo: str) -> int:
    """Kernels (fusions, copies, custom calls) launched per iteration of the outermost loop of a
    compiled module's text."""
    blocks = re.split(r"\n(?=\S)", hlo)
    entry = next(b for b in blocks if b.startswith("ENTRY"))
    body = re.search(r"while\([^\n]*body=%?([\w.\-]+)", entry).group(1)
    block = next(b for b in blocks if re.match(r"%?" + re.escape(body) + r" ", b))
    return len(re.findall(r"^\s*(?:ROOT )?%?\S+ = (?:\(.*?\)|\S+) (?:fusion|copy|custom-call)\(",
                          block, re.MULTILINE))


def gpu_step(batch: int, steps: int, repeats: int, unrolls: list[int]) -> None:
    import jax
    import jax.numpy as jnp

    import specrl_jax
    from specrl_jax.automata import compile_spec, stack, step_in_batch

    env, params = specrl_jax.make("LetterLTL0-v0")
    props = env.propositions
    _, formulas, _, _ = paper_cases()[0]
    specs = stack([compile_spec(f, props, np.asarray(env.alphabet)) for f in formulas])
    spec_ids = jnp.arange(batch) % len(formulas)

    # every variant reduces what it uses into the carry, so XLA cannot drop that work; the
    # label (`info["propositions"]`) is part of a LetterWorld step's output, so the baseline
    # consumes it too ("env"); "env, obs only" shows what computing the label itself costs.
    # The automaton's outputs are kept per env (state, accepting-visit count), as an evaluator
    # keeps them.
    def env_step(state, key):
        keys = jax.random.split(key, batch)
        actions = jax.random.randint(key, (batch,), 0, 4)
        obs, state, _, _, _, info = jax.vmap(env.step, (0, 0, 0, None))(keys, state, actions, params)
        return obs["ap"].sum(dtype=jnp.int32), state, info["propositions"]

    def obs_only(carry, key):
        state, total = carry
        seen, state, _ = env_step(state, key)
        return (state, total + seen), ()

    def env_only(carry, key):
        state, total = carry
        seen, state, labels = env_step(state, key)
        return (state, total + seen + labels.sum(dtype=jnp.int32)), ()

    def with_consumer(carry, key):  # what any per-env consumer of the label costs: no table
        state, total, q, visits = carry
        seen, state, labels = env_step(state, key)
        hit = labels.any(-1)
        return (state, total + seen + labels.sum(dtype=jnp.int32), q + hit, visits + hit), ()

    def with_automaton(carry, key):
        state, total, q, visits = carry
        seen, state, labels = env_step(state, key)
        q, acc, _, _ = jax.vmap(step_in_batch, (None, 0, 0, 0, None))(
            specs, spec_ids, q, labels, False)
        return (state, total + seen + labels.sum(dtype=jnp.int32), q, visits + acc), ()

    key = jax.random.key(0)
    _, state = jax.vmap(env.reset, (0, None))(jax.random.split(key, batch), params)
    q0 = specs.init[spec_ids]
    keys = jax.random.split(key, steps)
    zero = jnp.int32(0)
    variants = {}
    for unroll in unrolls:
        scanned = lambda body, u=unroll: jax.jit(lambda c: jax.lax.scan(body, c, keys, unroll=u)[0])
        per_env = (q0, jnp.zeros(batch, jnp.int32))
        for name, body, arg in (
                ("env, obs only", obs_only, (state, zero)),
                ("env", env_only, (state, zero)),
                ("env+consumer", with_consumer, (state, zero, *per_env)),
                ("env+automaton", with_automaton, (state, zero, *per_env))):
            fn = scanned(body).lower(arg).compile()
            jax.block_until_ready(fn(arg))
            variants[unroll, name] = (fn, arg, scan_body_kernels(fn.as_text()))
    timings = dict.fromkeys(variants, float("inf"))
    for _ in range(repeats):  # interleaved, so drifting clocks hit every variant alike
        for v, (fn, arg, _) in variants.items():
            t = time.perf_counter()
            jax.block_until_ready(fn(arg))
            timings[v] = min(timings[v], time.perf_counter() - t)
    print(f"batch {batch}, {len(formulas)} specs, {jax.devices()[0].device_kind}, "
          f"jax {jax.__version__}, best of {repeats} x {steps} steps")
    for (unroll, name), best in timings.items():
        per_iteration = variants[unroll, name][2] / unroll
        print(f"unroll {unroll} {name:14s}: {batch * steps / best:.3e} steps/s, "
              f"{1e6 * best / steps:6.2f} us/step, {per_iteration:g} kernels/step")
    for unroll in unrolls:
        over = timings[unroll, "env+automaton"] / timings[unroll, "env"] - 1
        label = timings[unroll, "env"] / timings[unroll, "env, obs only"] - 1
        extra = 1e6 * (timings[unroll, "env+automaton"] - timings[unroll, "env"]) / steps
        floor = timings[unroll, "env+consumer"] / timings[unroll, "env"] - 1
        print(f"unroll {unroll}: automaton overhead {100 * over:+.1f}% ({extra:.2f} us/step) over "
              f"a step with its label; a table-free label consumer {100 * floor:+.1f}%; the label "
              f"itself {100 * label:+.1f}% over obs only")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--gpu-step", action="store_true")
    parser.add_argument("--batch", type=int, default=65536)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--unroll", type=int, nargs="+", default=[1, 2],
                        help="lax.scan unroll factors to time the step loop under")
    args = parser.parse_args()
    if args.child:
        return child(args)
    if args.gpu_step:
        return gpu_step(args.batch, args.steps, args.repeats, args.unroll)
    cache = tempfile.mkdtemp(prefix="specrl_automata_")
    env = dict(os.environ, SPECRL_JAX_CACHE_DIR=cache, JAX_PLATFORMS="cpu")
    try:
        for label in ("cold", "cached"):
            res = subprocess.run([sys.executable, __file__, "--child"], env=env, check=True,
                                 capture_output=True, text=True).stdout.split()
            print(f"{label}: {float(res[0]):.3f} s for {res[1]} formulas; {res[5]} LetterWorld "
                  f"specs: bytes min {res[4]}, max {res[2]}, mean {res[3]}")
    finally:
        shutil.rmtree(cache, ignore_errors=True)


if __name__ == "__main__":
    main()
