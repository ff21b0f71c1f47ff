"""The DeepLTL candidate search past its budget: time, peak memory and complete states.

Each case runs in a fresh process (peak RSS is per process): `F a & ... & F <k-th letter>` over
LetterWorld's alphabet (2**k automaton states, k! simple paths from the initial state), and the
longest reach-avoid chain of the complexity grid (`seq10_disj0` from a).

    python benchmarks/automata_search_limits.py [--terms 8 9 10]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
LETTERS = tuple("abcdefghijkl")


def child(formula: str) -> dict:
    import resource
    import time

    sys.path.insert(0, os.path.join(HERE, ".."))
    from specrl_jax.automata import candidates, translate, zero_or_one

    aut = translate.translate(formula, LETTERS, zero_or_one(len(LETTERS)))
    start = time.perf_counter()
    seqs = candidates.candidate_sequences(aut, max_sequences=64, max_length=24)
    seconds = time.perf_counter() - start
    live = ~aut.violation & ~(aut.success & aut.is_finite)
    return {"states": aut.num_states, "live": int(live.sum()),
            "complete": int(seqs.complete[live].sum()), "search_s": round(seconds, 2),
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--terms", type=int, nargs="+", default=[8, 9, 10])
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child)))
        return
    sys.path.insert(0, os.path.join(HERE, ".."))
    from specrl_jax.specs import formulas

    cases = [" & ".join(f"F {c}" for c in LETTERS[:k]) for k in args.terms]
    cases.append(formulas.cyclic_reach_avoid(LETTERS, 10, 1, 0))
    for formula in cases:
        out = subprocess.run([sys.executable, __file__, "--child", formula], check=True,
                             capture_output=True, text=True).stdout
        print(formula[:40], json.loads(out.strip().splitlines()[-1]), flush=True)


if __name__ == "__main__":
    main()
