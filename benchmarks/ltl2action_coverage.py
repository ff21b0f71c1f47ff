"""How well an LTL2Action training bank covers the paper's IND formulas (host, CPU).

A formula state's *patterns* are its syntax tree's (parent token, edge type, child token)
triples, every proposition as one token (`tasks.progression.formula_graph`). An IND state is
covered when the training bank's states hold all of its patterns; an IND formula when every state
of its progression closure is. Prints, per sampler: the bank's formulas, formula states, build
time, and the covered fraction of IND formulas (root state; whole closure) and of IND states.

    python benchmarks/ltl2action_coverage.py [--family letter] [--samplers curriculum Until_1_3_1_2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from specrl_jax import specs
from specrl_jax.baselines import ltl2action
from specrl_jax.envs.registry import make
from specrl_jax.tasks.progression import PROP_OFFSET, closure, formula_graph

ENVS = {"letter": "LetterLTL0-v0", "zone": "PointLTL0-v0"}


def patterns(formula, propositions) -> frozenset[tuple[int, int, int]]:
    """(parent token, edge type, child token) triples of a formula state; propositions as one."""
    tokens, parents, edges = formula_graph(formula, propositions)
    tokens = [min(t, PROP_OFFSET) for t in tokens]
    return frozenset((tokens[p], e, tokens[i]) for i, (p, e) in enumerate(zip(parents, edges))
                     if p >= 0)


def coverage(train_states, test_formulas, propositions, alphabet) -> dict[str, float]:
    """Covered fractions of the test formulas (root; closure) and of their closure's states."""
    seen = frozenset().union(*(patterns(f, propositions) for f in train_states))
    roots, whole, states = [], [], {}
    for text in test_formulas:
        bank, test_states = closure([text], propositions, alphabet)
        ok = {f: patterns(f, propositions) <= seen for f in test_states}
        roots.append(ok[test_states[int(bank.roots[0])]])
        whole.append(all(ok.values()))
        states.update(ok)
    return {"formulas_root": float(np.mean(roots)), "formulas_closure": float(np.mean(whole)),
            "states": float(np.mean(list(states.values()))), "num_test_states": len(states)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", default="letter", choices=list(ENVS))
    parser.add_argument("--samplers", nargs="+", default=["curriculum", "Until_1_3_1_2",
                                                          "Eventually_1_5_1_4"])
    parser.add_argument("--num-formulas", type=int, default=1024,
                        help="per sampled curriculum stage, or the whole bank of a sampler")
    args = parser.parse_args()
    world, _ = make(ENVS[args.family])
    props, alphabet = tuple(world.propositions), np.asarray(world.alphabet, bool)
    ind = specs.suite(f"{args.family}/finite/ind")
    for sampler in args.samplers:
        start = time.perf_counter()
        by_stage = ltl2action.training_formulas(props, args.family, args.num_formulas, 0, sampler)
        drawn = time.perf_counter() - start
        formulas = [f for stage in by_stage for f in stage]
        start = time.perf_counter()
        bank, states = closure(formulas, props, alphabet)
        built = time.perf_counter() - start
        cov = coverage(states, ind, props, alphabet)
        print(f"{args.family} {sampler} x{args.num_formulas}: {len(formulas)} formulas "
              f"({len(set(formulas))} distinct), {bank.num_states} formula states, drawn in "
              f"{drawn:.1f} s, closure in {built:.1f} s; IND covered: formulas "
              f"{cov['formulas_root']:.2f} (root) / {cov['formulas_closure']:.2f} (closure), "
              f"states {cov['states']:.2f} of "
              f"{cov['num_test_states']}")


if __name__ == "__main__":
    main()
