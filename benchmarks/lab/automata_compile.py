"""What compiling specs to automata costs, and where the candidate search meets its limits.

Parts (`--parts`):
  paper   every formula of the paper's spec tables, cold (an empty automata cache) and again
          from the disk cache; the bytes of each compiled LetterWorld spec;
  grid    the whole LetterWorld complexity grid, cold: total, slowest cell and formula, largest
          automaton, specs whose candidate lists hit the caps;
  search  the DeepLTL candidate search past its budget, each case in a fresh process (peak
          memory is per process): `F a & ... & F <k-th letter>` for k in `--terms` (2**k
          automaton states, k! simple paths) and the grid's longest reach-avoid chain.

`--limit N` takes the first N formulas of each table and cell, and the grid's N smallest cells
(a quick look). Prints one JSON row
per figure (`benchmarks/harness.py`), appended to `--out` if given.

    python benchmarks/lab/automata_compile.py --parts paper grid search --terms 8 9 10
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import harness

COLORS = ("blue", "green", "magenta", "yellow")
LETTERS = tuple("abcdefghijkl")


def paper_cases(limit: int | None) -> list[tuple[str, list[str], tuple, object]]:
    """(table, formulas, propositions, alphabet) for every spec table of the paper."""
    from specrl_jax import specs
    from specrl_jax.automata import all_subsets, product, zero_or_one

    arm = tuple(f"arm_{c}" for c in COLORS) + tuple(f"grippers_{c}" for c in COLORS)
    agents = tuple(f"{c}_{i}" for i in range(3) for c in COLORS)
    worlds = {
        "letter": (LETTERS, zero_or_one(12)),
        "zone": (COLORS, zero_or_one(4)),
        "arm_grippers": (COLORS, zero_or_one(4)),
        "arm_grippers_arm": (arm, all_subsets(8)),
        "multi_agent_zone": (agents, product(*[zero_or_one(4)] * 3)),
    }
    cases = []
    for name in specs.list_suites():
        world = name.split("/")[0]
        if world in worlds and ("/finite/" in name or "/infinite/" in name
                                or "/complexity_paper/" in name):
            cases.append((name, specs.suite(name)[:limit], *worlds[world]))
    return cases


def compile_paper(limit: int | None, out: str | None) -> None:
    from specrl_jax.automata import compile_spec

    cases = paper_cases(limit)
    count = sum(len(formulas) for _, formulas, _, _ in cases)
    seconds, sizes = {}, []
    for label in ("cold", "cached"):
        start = time.perf_counter()
        for name, formulas, props, alphabet in cases:
            for formula in formulas:
                spec = compile_spec(formula, props, alphabet)
                if label == "cold" and name.startswith("letter"):
                    sizes.append(spec.nbytes)
        seconds[label] = time.perf_counter() - start
    harness.emit(harness.row(
        f"Compile the paper's formulas ({count}, {len(cases)} suites), cold / from the disk cache",
        f"{seconds['cold']:.2f} s / {seconds['cached']:.2f} s", None, formulas=count), out)
    harness.emit(harness.row(
        f"Bytes per LetterWorld paper spec ({len(sizes)} specs), min / mean / max",
        f"{min(sizes):,} / {sum(sizes) / len(sizes):,.0f} / {max(sizes):,}", None), out)


def compile_grid(limit: int | None, out: str | None) -> None:
    from specrl_jax import specs
    from specrl_jax.automata import compile_spec, zero_or_one

    alphabet = zero_or_one(len(LETTERS))
    # cells from the shortest sequences up (with --limit, the first N cells)
    names = sorted(specs.list_suites("letter/complexity/"),
                   key=lambda n: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", n)])
    names = names[:limit] if limit else names
    per_cell, slowest, largest, dropped, count = {}, (0.0, ""), (0, ""), 0, 0
    start = time.perf_counter()
    for name in names:
        cell_start = time.perf_counter()
        for formula in specs.suite(name)[:limit]:
            formula_start = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                spec = compile_spec(formula, LETTERS, alphabet)
            dropped += sum("dropped" in str(w.message) for w in caught)
            slowest = max(slowest, (time.perf_counter() - formula_start, formula))
            largest = max(largest, (spec.num_states, formula))
            count += 1
        per_cell[name] = time.perf_counter() - cell_start
    total = time.perf_counter() - start
    worst = max(per_cell, key=per_cell.get)
    harness.emit(harness.row(
        f"Compile the complexity grid ({count} formulas, {len(names)} cells), cold",
        f"{total:.2f} s", None, slowest_cell=worst, slowest_cell_s=round(per_cell[worst], 3),
        slowest_formula=slowest[1], slowest_formula_s=round(slowest[0], 3),
        largest_states=largest[0], largest_formula=largest[1], capped_specs=dropped), out)


def search_child(formula: str) -> dict:
    import resource

    from specrl_jax.automata import candidates, translate, zero_or_one

    aut = translate.translate(formula, LETTERS, zero_or_one(len(LETTERS)))
    start = time.perf_counter()
    seqs = candidates.candidate_sequences(aut, max_sequences=64, max_length=24)
    seconds = time.perf_counter() - start
    live = ~aut.violation & ~(aut.success & aut.is_finite)
    return {"states": int(aut.num_states), "live": int(live.sum()),
            "complete": int(seqs.complete[live].sum()), "search_s": round(seconds, 2),
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024}


def search_limits(terms: list[int], chain: bool, out: str | None) -> None:
    from specrl_jax.specs import formulas

    cases = [" & ".join(f"F {c}" for c in LETTERS[:k]) for k in terms]
    if chain:
        cases.append(formulas.cyclic_reach_avoid(LETTERS, 10, 1, 0))
    for formula in cases:
        text = subprocess.run([sys.executable, __file__, "--search-child", formula], check=True,
                              capture_output=True, text=True).stdout
        result = json.loads(text.strip().splitlines()[-1])
        value = (f"{result['complete']} of {result['live']} live states complete, "
                 f"{result['search_s']} s, {result['peak_mb']} MB peak")
        harness.emit(harness.row(f"Candidate search: {formula[:60]}", value, None, **result), out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="+", choices=["paper", "grid", "search"],
                        default=["paper"])
    parser.add_argument("--limit", type=int, default=None,
                        help="first N formulas of each table and cell, N smallest grid cells")
    parser.add_argument("--terms", type=int, nargs="+", default=[8, 9, 10])
    parser.add_argument("--no-chain", action="store_true",
                        help="search: leave out the grid's longest chain")
    parser.add_argument("--search-child", help=argparse.SUPPRESS)
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    if args.search_child:
        print(json.dumps(search_child(args.search_child)))
        return
    # empty caches (the automata cache is read at each compile), so "cold" is cold
    with tempfile.TemporaryDirectory(prefix="specrl_automata_") as root:
        os.environ["SPECRL_JAX_CACHE_DIR"] = os.path.join(root, "paper")
        if "paper" in args.parts:
            compile_paper(args.limit, args.out)
        os.environ["SPECRL_JAX_CACHE_DIR"] = os.path.join(root, "grid")
        if "grid" in args.parts:
            compile_grid(args.limit, args.out)
        if "search" in args.parts:
            search_limits(args.terms, not args.no_chain, args.out)


if __name__ == "__main__":
    main()
