"""Compile the whole LetterWorld complexity grid (2 kinds x 9 lengths x 4 disjunction counts x
10 formulas) with an empty disk cache; report the total, the slowest cell and formula, and the
largest automaton.

    python benchmarks/complexity_grid_compile.py
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main() -> None:
    os.environ["SPECRL_JAX_CACHE_DIR"] = tempfile.mkdtemp(prefix="specrl_grid_")
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import specrl_jax
    from specrl_jax import specs
    from specrl_jax.automata import compile_spec, zero_or_one

    alphabet = zero_or_one(len(specs.suites.LETTERS))
    names = specs.list_suites("letter/complexity/")
    per_cell, slowest, largest, dropped = {}, (0.0, ""), (0, ""), 0
    start = time.perf_counter()
    for name in names:
        t_cell = time.perf_counter()
        for formula in specs.suite(name):
            t0 = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                spec = compile_spec(formula, specs.suites.LETTERS, alphabet)
            dropped += sum("dropped" in str(w.message) for w in caught)
            seconds = time.perf_counter() - t0
            slowest = max(slowest, (seconds, formula))
            largest = max(largest, (spec.num_states, formula))
        per_cell[name] = time.perf_counter() - t_cell
    total = time.perf_counter() - start
    count = sum(len(specs.suite(n)) for n in names)
    worst_cell = max(per_cell, key=per_cell.get)
    print(f"grid: {count} formulas in {len(names)} cells compiled cold in {total:.2f} s "
          f"(specrl_jax {specrl_jax.__version__})")
    print(f"slowest cell: {worst_cell} {per_cell[worst_cell]:.2f} s")
    print(f"slowest formula: {slowest[0]:.3f} s  {slowest[1]}")
    print(f"largest automaton: {largest[0]} states  {largest[1]}")
    print(f"specs whose candidate lists hit the caps: {dropped}")


if __name__ == "__main__":
    main()
