"""Compile every formula of the paper's spec tables: cold (empty disk cache) and from the cache.

Also reports the bytes of each compiled LetterWorld spec, and with --gpu-step the cost of the
automaton step inside three kinds of LetterWorld step at a large batch (see `gpu_step`), next to
a table-free consumer of the label (what any extra per-env kernel costs), with the kernels per
loop iteration.

    python benchmarks/automata_compile.py [--gpu-step --batch 65536 --steps 300 --unroll 1 2]
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
    from specrl_jax.envs.wrappers import batch as batched_env
    from specrl_jax.tasks import TaskEnv

    env, params = specrl_jax.make("LetterLTL0-v0")
    _, formulas, _, _ = paper_cases()[0]
    specs = stack([compile_spec(f, env.propositions, np.asarray(env.alphabet)) for f in formulas])
    spec_ids = jnp.arange(batch) % len(formulas)
    key = jax.random.key(0)

    # Three LetterWorld steps: "raw" (no resets) folds the observation into a checksum, so XLA
    # never writes it; "raw, obs out" writes it each step, as anything that uses it must;
    # "auto-reset" is `batch(env, B)` with the opt-in map-bank resets (the fastest resetting
    # step; the default exact resets are far dearer, see docs/results.md). Every variant folds labels
    # and done flags into the checksum too. The automaton's outputs are kept per env, as an
    # evaluator keeps them.
    # "task" is the whole task layer on the same resetting world: `TaskEnv.step` (automaton,
    # reward, termination, spec and layout resets), timed against "auto-reset".
    raw = lambda k, s, a: jax.vmap(env.step, (0, 0, 0, None))(jax.random.split(k, batch), s, a,
                                                               params)
    resetting, bank_params = batched_env(env, batch), env.with_map_bank(key, params)
    resetting_step = lambda k, s, a: resetting.step(k, s, a, bank_params)
    _, raw_state = jax.vmap(env.reset, (0, None))(jax.random.split(key, batch), params)
    _, resetting_state = jax.jit(resetting.reset)(key, bank_params)
    task = TaskEnv(env, specs)
    task_step = lambda k, s, a: jax.vmap(task.step, (0, 0, 0, None))(jax.random.split(k, batch),
                                                                       s, a, bank_params)
    _, task_state = jax.jit(jax.vmap(task.reset, (0, None, 0)))(
        jax.random.split(key, batch), bank_params, spec_ids)
    worlds = {"raw": (raw, raw_state, False), "raw, obs out": (raw, raw_state, True),
              "auto-reset": (resetting_step, resetting_state, False),
              "task": (task_step, task_state, False)}

    # label consumers: none; a table-free one (what any extra per-env kernel costs); the
    # automaton from the label; the automaton from the env's symbol (what TaskEnv does)
    def consumer(info, q):
        hit = info["propositions"].any(-1)
        return q + hit, hit

    def from_label(info, q):
        return jax.vmap(step_in_batch, (None, 0, 0, 0, None))(
            specs, spec_ids, q, info["propositions"], False)[:2]

    def from_symbol(info, q):
        return jax.vmap(step_in_batch, (None, 0, 0, 0, None, 0))(
            specs, spec_ids, q, info["propositions"], False, info["symbol"])[:2]

    consumers = {"": None, "+consumer": consumer, "+automaton (label)": from_label,
                 "+automaton (symbol)": from_symbol}

    def loop(world_step, obs_out, consume):
        def body(carry, step_key):
            state, total, q, visits, obs = carry
            key_action, key_step = jax.random.split(step_key)
            actions = jax.random.randint(key_action, (batch,), 0, 4)
            new_obs, state, _, terminated, truncated, info = world_step(key_step, state, actions)
            total += (info["propositions"].sum(dtype=jnp.int32)
                      + (terminated | truncated).sum(dtype=jnp.int32))
            if obs_out:
                obs = new_obs["ap"]
            else:
                total += new_obs["ap"].sum(dtype=jnp.int32)
            if consume is not None:
                q, hit = consume(info, q)
                visits += hit
            return (state, total, q, visits, obs), ()
        return body

    carry_tail = (jnp.int32(0), specs.init[spec_ids], jnp.zeros(batch, jnp.int32),
                  jnp.zeros((batch, *env.observation_space["ap"].shape), jnp.uint8))
    keys = jax.random.split(key, steps)
    variants, outputs = {}, {}
    for unroll in unrolls:
        for world, (world_step, state, obs_out) in worlds.items():
            for name, consume in consumers.items() if world != "task" else [("", None)]:
                body = loop(world_step, obs_out, consume)
                fn = jax.jit(lambda c, body=body, u=unroll: jax.lax.scan(body, c, keys,
                                                                         unroll=u)[0])
                arg = (state, *carry_tail)
                compiled = fn.lower(arg).compile()
                outputs[unroll, world, name] = jax.block_until_ready(compiled(arg))
                variants[unroll, world, name] = (compiled, arg,
                                                 scan_body_kernels(compiled.as_text()))
    for unroll in unrolls:  # the symbol gives the label's runs
        for world in set(worlds) - {"task"}:
            a, b = (outputs[unroll, world, f"+automaton ({k})"] for k in ("label", "symbol"))
            assert all(bool((x == y).all()) for x, y in zip(a[2:4], b[2:4])), world
    timings = dict.fromkeys(variants, float("inf"))
    for _ in range(repeats):  # interleaved, so drifting clocks hit every variant alike
        for v, (fn, arg, _) in variants.items():
            t = time.perf_counter()
            jax.block_until_ready(fn(arg))
            timings[v] = min(timings[v], time.perf_counter() - t)
    print(f"batch {batch}, {len(formulas)} specs, {jax.devices()[0].device_kind}, "
          f"jax {jax.__version__}, best of {repeats} x {steps} steps")
    for (unroll, world, name), best in timings.items():
        base = timings[unroll, "auto-reset" if world == "task" else world, ""]
        kernels = variants[unroll, world, name][2] / unroll
        print(f"unroll {unroll} {world + name:36s} {1e6 * best / steps:7.2f} us/step "
              f"{1e6 * (best - base) / steps:+6.2f} us {100 * (best / base - 1):+6.1f}%  "
              f"{kernels:g} kernels/step")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--gpu-step", action="store_true")
    parser.add_argument("--batch", type=int, default=65536)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--unroll", type=int, nargs="+", default=[1],
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
