"""Cost of the original-automaton tracker beside our automaton step, per batch of episodes.

For each suite: B episodes (a stack of the suite's specs, episode i on spec i mod N), T steps of
pseudo-random labels (an LCG carried per episode, so label generation costs next to nothing);
timed: our `automata.step_in_batch` alone, then with `eval.original_ldba.step` beside it under
each rule. Prints automaton steps per second (one step = one episode advanced one label).

    python benchmarks/original_ldba_throughput.py [--batch 65536] [--steps 1000]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata, specs
from specrl_jax.automata import product, zero_or_one
from specrl_jax.eval import original_ldba as ol

SUITES = ("letter/infinite/rsp", "letter/infinite/rec", "zone/infinite/per",
          "multi_agent_zone/infinite/rsp")


def make_run(bank, ldbas, batch: int, steps: int, rule: str | None):
    num_specs = bank.delta.shape[0]
    num_symbols = bank.alphabet.shape[1]
    spec_id = jnp.arange(batch, dtype=jnp.int32) % num_specs
    pick = lambda tree: jax.tree.map(lambda x: x[spec_id], tree)  # noqa: E731

    @jax.jit
    def run(seed):
        lcg = jnp.arange(batch, dtype=jnp.uint32) * jnp.uint32(2654435761) + seed
        q = bank.init[spec_id]
        mine = pick(ldbas)
        tracker = jax.vmap(ol.init)(mine)

        def body(carry, _):
            lcg, q, count, tracker, orig = carry
            lcg = lcg * jnp.uint32(1664525) + jnp.uint32(1013904223)
            symbol = ((lcg >> 16) % num_symbols).astype(jnp.int32)
            props = bank.alphabet[0][symbol]
            q, acc, _, _ = jax.vmap(automata.step_in_batch, (None, 0, 0, 0, None, 0))(
                bank, spec_id, q, props, False, symbol)
            if rule is not None:
                tracker, accepted = jax.vmap(
                    lambda l, t, s: ol.step(l, t, s, False, rule=rule))(mine, tracker, symbol)
                orig = orig + accepted
            return (lcg, q, count + acc, tracker, orig), None

        zeros = jnp.zeros(batch, jnp.int32)
        carry, _ = jax.lax.scan(body, (lcg, q, zeros, tracker, zeros), None, length=steps)
        return carry[2].sum(), carry[4].sum()

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=65_536)
    parser.add_argument("--steps", type=int, default=1_000)
    args = parser.parse_args()
    print(f"jax {jax.__version__}, device {jax.devices()[0]}, batch {args.batch}, "
          f"steps {args.steps}")
    for name in SUITES:
        info = specs.suite_info(name)
        alphabet = (product(zero_or_one(4), zero_or_one(4))
                    if info.alphabet == "per_agent_zero_or_one"
                    else zero_or_one(len(info.propositions)))
        bank = automata.stack([automata.compile_spec(f, info.propositions, alphabet=alphabet)
                               for f in info.formulas])
        world = type("W", (), {"propositions": info.propositions, "alphabet": alphabet})()
        ldbas = ol.suite_ldbas(name, world)
        for rule in (None, "policy", "hindsight"):
            run = make_run(bank, ldbas, args.batch, args.steps, rule)
            start = time.perf_counter()
            jax.block_until_ready(run(jnp.uint32(1)))
            compile_s = time.perf_counter() - start
            best = np.inf
            for seed in (2, 3):
                start = time.perf_counter()
                jax.block_until_ready(run(jnp.uint32(seed)))
                best = min(best, time.perf_counter() - start)
            rate = args.batch * args.steps / best
            print(f"{name} (original S={ldbas.delta.shape[1]}): ours"
                  f"{'' if rule is None else ' + tracker ' + rule}: {rate / 1e9:.2f}G steps/s "
                  f"({best * 1e3:.1f} ms, first call {compile_s:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
