"""How long `specrl-jax bench` takes, and the Gymnasium backend's episodes per second.

    python benchmarks/bench_speed.py --part bench --out bench_speed.jsonl       # a GPU: every world
    python benchmarks/bench_speed.py --part gymnasium --out bench_speed.jsonl   # a CPU: both backends

`bench`: for each world, `bench.score` of the results store's GenZ-LTL cell (seed 1's parameters
under 5 evaluation seeds) on every paper suite of the world, 5 seeds x 100 episodes, timed from the
call to the written report (compilation included; the JAX cache is off so nothing is reused);
the multi-agent world by its coordinator cell (PointLTL0-v0/genz's seed 1 on every agent).

`gymnasium`: one deterministic policy written twice (JAX, numpy) on LetterWorld's finite IND
suite: episodes per second of each backend, timed on a second identical call (the first compiles;
the second finds the programs in JAX's persistent cache, or in the process for the vector env).
Each figure is printed as one JSON line and appended to `--out`.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import harness  # noqa: E402  (the benchmark harness beside this script)

#: world -> the store cell whose parameters are scored
CELLS = {"letter": "LetterLTL0-v0/genz", "zone": "PointLTL0-v0/genz",
         "arm": "PandaLTLReach0Joints-v0/genz", "multi_agent": "PointLTL0MA2-v0/genz+coordinator"}


def time_bench(worlds: list[str], seeds: int, episodes: int, out: str | None) -> None:
    from specrl_jax.benchmark import bench

    for world in worlds:
        cell = CELLS[world]
        env_id = cell.split("/")[0]
        with tempfile.TemporaryDirectory() as report_dir:
            start = time.perf_counter()
            report = bench.score(cell, worlds=[env_id], seeds=seeds, episodes=episodes,
                                 out=report_dir, log=lambda line: None)
            wall = time.perf_counter() - start
        (score,) = report.worlds
        harness.emit(harness.row(
            f"specrl-jax bench wall time with compilation, {world} ({cell}), s", round(wall, 1),
            suites=len(score.results), seeds=seeds, episodes=episodes, summary=score.line()), out)


def _jax_policy(params, obs, task_state, key):
    import jax.numpy as jnp

    ap = obs["ap"]
    centre = ap.shape[0] // 2
    return ((ap[centre - 1].sum() + 2 * ap[:, centre + 1].sum() + task_state.q) % 4).astype(jnp.int32)


def _numpy_policy(obs, task):
    ap = obs[..., :-1]
    centre = ap.shape[1] // 2
    return ((ap[:, centre - 1].sum(axis=(1, 2)) + 2 * ap[:, :, centre + 1].sum(axis=(1, 2))
            + task.q) % 4).astype(np.int64)  # uint64 + int32 would be float64


def time_backends(seeds: int, episodes: int, num_envs: int, out: str | None) -> None:
    from specrl_jax import specs
    from specrl_jax.benchmark import bench

    suite = "letter/finite/ind"
    count = seeds * len(specs.suite(suite)) * episodes
    for backend, policy in (("jax", _jax_policy), ("gymnasium", _numpy_policy)):
        lines: list[str] = []
        options = {"worlds": ["LetterLTL0-v0"], "suites": [suite], "backend": backend,
                   "num_envs": num_envs, "seeds": seeds, "episodes": episodes}
        start = time.perf_counter()
        bench.score(policy, log=lambda line: None, **options)  # compiles
        warm = time.perf_counter() - start
        start = time.perf_counter()
        bench.score(policy, log=lines.append, **options)
        wall = time.perf_counter() - start
        # the episodes alone: the evaluator's (or the vector env's waves') own timing lines
        run = sum(float(m) for m in re.findall(r"episodes x \d+ steps in ([\d.]+)s", "\n".join(lines)))
        harness.emit(harness.row(
            f"{backend} backend, LetterWorld {suite}, episodes/s", round(count / max(run, 1e-9), 1),
            num_envs, episodes=count, episodes_s=round(run, 2), wall_s_second_call=round(wall, 2),
            wall_s_first_call=round(warm, 1)), out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("bench", "gymnasium"), required=True)
    parser.add_argument("--worlds", default=",".join(CELLS), help="bench: comma-separated")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--num-envs", type=int, default=2048, help="gymnasium: envs side by side")
    parser.add_argument("--out", default=None, help="JSON-lines file to append to")
    args = parser.parse_args(argv)
    if args.part == "bench":
        os.environ.setdefault("SPECRL_JAX_CACHE_DIR", "off")  # compilation is part of the figure
        time_bench([w.strip() for w in args.worlds.split(",")], args.seeds, args.episodes,
                   args.out)
    else:
        time_backends(args.seeds, args.episodes, args.num_envs, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
