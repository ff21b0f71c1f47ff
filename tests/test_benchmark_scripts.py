"""Every benchmark script (benchmarks/ and benchmarks/lab/) runs at a tiny size on the CPU.

Each script runs in a fresh process with tiny arguments and must exit 0 and write its result rows
(`benchmarks/harness.py`: one JSON object per line with the figure, its value, device, batch,
versions, date and command). Scripts that need a package CI lacks (PyBullet) or a CUDA GPU are
skipped for that reason only. A new script must be added to `SCRIPTS`, or to `OWN_TEST` when a
test file of its own runs it (the listing test fails otherwise), so nothing under benchmarks/
rots unseen.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"

#: script -> tiny arguments (`--out ROWS` is added); the compiled shapes are kept small
SCRIPTS = {
    "env_throughput.py": ["--envs", "LetterLTL0-v0", "--batches", "4", "--steps", "2",
                          "--repeats", "1", "--loops", "world", "task", "--resets", "bank",
                          "--bank-size", "4", "--determinism"],
    "lab/automata_compile.py": ["--parts", "paper", "grid", "search", "--limit", "1",
                                "--terms", "2", "--no-chain"],
    "lab/zone_physics.py": ["--robots", "Point", "--steps", "2", "--seeds", "1",
                            "--matmul-precision", "highest"],
    "lab/vision_fidelity.py": ["--robots", "Point", "--supersample", "1"],
    "lab/arm_vs_pybullet.py": ["--episodes", "2", "--steps", "3"],
    "lab/warp_profile.py": ["--robots", "Point", "--worlds", "4", "--substeps", "2"],
    "lab/avoid_sets.py": ["--episodes", "1", "--horizon", "5", "--keep", "0", "--subgoals"],
    "lab/arm_solver_load.py": ["--policy", "random", "--suites", "arm_grippers/finite/ind",
                               "--episodes", "1", "--steps", "2"],
    "lab/image_conv.py": ["--seeds", "2", "--cases", "64:2", "--repeats", "1", "--in-turn"],
    "lab/arm_motor_solve.py": ["--batches", "8", "--repeats", "1"],
    "lab/arm_grippers_alone.py": ["--episodes", "2", "--steps", "2", "--heights", "0.05"],
    "lab/curriculum_pairs.py": ["--policy", "random", "--env", "LetterLTL0-v0", "--episodes", "1"],
    "lab/coordinator_actions.py": ["--cells", "PointLTL0MA2-v0/genz+coordinator", "--episodes", "1",
                                   "--horizon", "3"],
    "lab/infinite_episodes.py": ["--methods", "genz", "--suites", "zone/infinite/per",
                                 "--horizon", "5", "--summary", "episodes.json",
                                 "--plot-paths", "paths.png"],
    "lab/arm_solve_capacity.py": ["--policy", "random", "--capacities", "1.0", "--episodes", "1",
                                  "--steps", "2"],
    "lab/curve_agreement.py": [
        str(ROOT / "benchmarks/results/pointltl0vision64_deepltl_partial_metrics_h200.jsonl"),
        str(ROOT / "specrl_jax/benchmark/results/PointLTL0Vision-v0__deepltl/metrics.jsonl"),
        "--window", "50", "--plot", "curves.png"],
    "bench_speed.py": ["--part", "gymnasium", "--seeds", "1", "--episodes", "1",
                       "--num-envs", "4"],
}
#: the result file's flag, where a script names it otherwise than `--out`
ROW_FLAG = {"lab/vision_fidelity.py": "--rows"}
#: scripts whose output is one JSON document of their own, not harness rows
OWN_JSON = {"lab/arm_vs_pybullet.py"}
#: the harness module itself
NOT_SCRIPTS = {"harness.py"}
#: scripts smoke-run by a test file of their own
OWN_TEST = {"train_profile.py": "tests/test_train_profile.py", "pack_warp.py": "tests/test_pack_warp.py"}
ROW_KEYS = {"figure", "value", "device", "batch", "versions", "date", "command"}


def test_every_script_has_a_smoke_run():
    found = {str(p.relative_to(BENCHMARKS)) for p in BENCHMARKS.glob("*.py")}
    found |= {str(p.relative_to(BENCHMARKS)) for p in BENCHMARKS.glob("lab/*.py")}
    assert all((ROOT / test).is_file() for test in OWN_TEST.values())
    assert found - NOT_SCRIPTS - set(OWN_TEST) == set(SCRIPTS)


def _needs(script: str) -> None:
    """Skip for a missing optional dependency, naming it."""
    if script == "lab/arm_vs_pybullet.py":
        pytest.importorskip("pybullet", reason="PyBullet (the optional `pybullet` extra)")
    if script == "lab/warp_profile.py":
        warp = pytest.importorskip("warp", reason="warp-lang (the optional `warp` extra)")
        if not warp.is_cuda_available():
            pytest.skip("needs a CUDA GPU: MuJoCo Warp times its stages with CUDA events")


@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_script_runs_tiny(script, tmp_path):
    _needs(script)
    out = tmp_path / "rows.json"
    env = dict(os.environ, JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
    command = [sys.executable, str(BENCHMARKS / script), *SCRIPTS[script],
               ROW_FLAG.get(script, "--out"), str(out)]
    if script == "lab/vision_fidelity.py":
        command += ["--out", str(tmp_path / "frames.png")]
    done = subprocess.run(command, check=False, cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, f"{script} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    assert out.exists(), f"{script} wrote no results"
    if script in OWN_JSON:
        assert json.loads(out.read_text())
        return
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert rows, f"{script} wrote no rows"
    for row in rows:
        assert ROW_KEYS <= set(row), f"{script}: a row lacks {ROW_KEYS - set(row)}"
    printed = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert len(printed) == len(rows), f"{script} printed {len(printed)} rows, wrote {len(rows)}"


def test_device_prelude_parses():
    """The shell script sourced on a lent GPU machine is at least valid bash."""
    subprocess.run(["bash", "-n", str(BENCHMARKS / "device_prelude.sh")], check=True)


def test_device_reproduce_starts_from_the_package_store_and_brings_back_what_it_wrote(tmp_path):
    """`device_reproduce.sh` runs `reproduce` with its arguments on a store copied from the
    package's, packs for $OUT the files written since, without scratch/ or files over KEEP_MB
    (listed in the log, as are files the run deleted), and exits with reproduce's status. The
    run directories of cells not done come back apart (scratch.tar.gz), and carried ones start
    a new machine's store."""
    import tarfile

    site, store, out = tmp_path / "site", tmp_path / "store", tmp_path / "out"
    carried = tmp_path / "carried"
    site.mkdir()
    (site / ".installed").touch()  # the packages are there: the prelude installs nothing
    env = {**os.environ, "SPECRL_SITE": str(site), "STORE": str(store), "OUT": str(out),
           "KEEP_MB": "1", "CARRIED": str(carried),
           "PATH": f"{pathlib.Path(sys.executable).parent}:{os.environ['PATH']}"}

    def packed(name: str) -> list[str]:
        if not (out / name).exists():
            return []
        with tarfile.open(out / name) as tar:
            return sorted(n for n in tar.getnames() if tar.getmember(n).isfile())

    def call(*args: str) -> tuple[int, str, list[str]]:
        if out.exists():
            for old in out.iterdir():
                old.unlink()
        out.mkdir(exist_ok=True)
        done = subprocess.run(["bash", str(BENCHMARKS / "device_reproduce.sh"), *args], env=env,
                              cwd=tmp_path, capture_output=True, text=True, check=False)
        (log,) = out.glob("reproduce_*.log")
        return done.returncode, log.read_text(), packed("cells.tar.gz")

    listing = ("--list", "--cells", "LetterLTL0-v0/genz")
    rc, log, files = call(*listing)
    assert rc == 0 and files == []  # the package's store, copied: nothing written yet
    assert "LetterLTL0-v0/genz" in log and "PointLTL0-v0" not in log and "done" in log
    cell = store / "LetterLTL0-v0__genz"
    (store / "scratch" / "Demo__x").mkdir(parents=True)
    (store / "scratch" / "Demo__x" / "checkpoint.msgpack").write_bytes(b"\0")
    (cell / "params_seed1.msgpack").write_bytes(b"\0" * (2 << 20))
    (cell / "notes.json").write_text("{}")
    (cell / "cell.json").unlink()
    rc, log, files = call(*listing)
    assert rc == 0 and files == ["./LetterLTL0-v0__genz/notes.json"]
    assert "missing" in log  # reproduce read the copied store
    assert "left behind (too large): ./LetterLTL0-v0__genz/params_seed1.msgpack" in log
    assert "deleted by the run: ./LetterLTL0-v0__genz/cell.json" in log
    # the runs of cells not done come back whole, together at most KEEP_MB; a done cell's stays
    assert packed("scratch.tar.gz") == []
    run = store / "scratch" / "LetterLTL0-v0__genz" / "run"
    part = store / "scratch" / "LetterLTL0-v0__deepltl" / "run_seeds3-5"
    for directory in (run, part):
        directory.mkdir(parents=True)
        (directory / "checkpoint.msgpack").write_bytes(b"\1")
    (store / "LetterLTL0-v0__deepltl" / "cell.json").unlink()
    (run / "big.msgpack").write_bytes(b"\0" * (2 << 20))
    (store / "scratch" / "PointLTL0-v0__genz").mkdir()
    rc, log, files = call(*listing)
    assert packed("scratch.tar.gz") == ["LetterLTL0-v0__deepltl/run_seeds3-5/checkpoint.msgpack"]
    assert "over the 1024 kB that come back" in log and "./scratch/LetterLTL0-v0__genz" in log
    assert "PointLTL0-v0__genz" not in log
    (run / "big.msgpack").unlink()
    rc, log, files = call(*listing)
    assert packed("scratch.tar.gz") == ["LetterLTL0-v0__deepltl/run_seeds3-5/checkpoint.msgpack",
                                        "LetterLTL0-v0__genz/run/checkpoint.msgpack"]
    assert "resumable run brought back (scratch.tar.gz): LetterLTL0-v0__genz" in log
    # a new machine's store starts from the carried runs; a store's own run is kept, FRESH too
    # (STORE with a trailing slash included)
    with tarfile.open(out / "scratch.tar.gz") as tar:
        tar.extractall(carried, filter="data")
    (run / "checkpoint.msgpack").write_bytes(b"\2")
    env["FRESH"], env["STORE"] = "1", f"{store}/"
    rc, log, files = call(*listing)
    del env["FRESH"]
    assert "resuming from the carried run" not in log and "LetterLTL0-v0__genz kept" in log
    assert (run / "checkpoint.msgpack").read_bytes() == b"\2"
    # a call killed with the runs set aside beside the store: the next puts them back
    shutil.rmtree(store)
    kept = tmp_path / ".store.kept_scratch" / "Demo__y"
    kept.mkdir(parents=True)
    rc, log, files = call(*listing)
    assert rc == 0 and (store / "scratch" / "Demo__y").is_dir() and not kept.parent.exists()
    assert "resuming from the carried run directory: LetterLTL0-v0__genz" in log
    # a copy of a carried run killed half-way: the next copy starts it again
    shutil.rmtree(run.parent)
    stale = store / "scratch" / ".LetterLTL0-v0__genz.part"
    stale.mkdir()
    (stale / "stale.json").write_text("{}")
    rc, log, files = call(*listing)
    assert "resuming from the carried run directory: LetterLTL0-v0__genz" in log
    assert (run / "checkpoint.msgpack").read_bytes() == b"\1"
    assert sorted(p.name for p in run.parent.iterdir()) == ["run"] and not stale.exists()
    rc, log, files = call("--seed-range", "5-1")
    assert rc != 0 and files == []


def test_curve_agreement_compares_whole_windows_of_matched_updates(tmp_path):
    import importlib.util

    sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("curve_agreement", BENCHMARKS / "lab/curve_agreement.py")
    lab = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(lab)
    rng = np.random.default_rng(0)
    base = rng.uniform(0.2, 0.4, (25, 5))
    same = lab.windows(base, base + rng.normal(0, 0.01, base.shape), 10)
    assert [w["updates"] for w in same] == [[1, 10], [11, 20]]  # the 5-update tail is left out
    assert all(w["within_two_se"] for w in same)
    assert not any(w["within_two_se"] for w in lab.windows(base, base + 0.5, 10))
    with pytest.raises(ValueError, match="choose 1 to 25"):
        lab.windows(base, base, 0)
    # rows matched by update: a resumed run's repeated update replaces the earlier row
    path = tmp_path / "m.jsonl"
    rows = [(1, [0.0, 1.0]), (2, [0.5, 0.5]), (2, [0.2, 0.2]), (3, [1.0, 1.0])]
    path.write_text("".join(json.dumps({"update": u, "success_rate_seeds": s}) + "\n" for u, s in rows))
    a, b = lab.aligned(lab.success_per_seed(str(path)), {1: [0, 0], 2: [0, 0]})
    assert a.tolist() == [[0.0, 1.0], [0.2, 0.2]] and b.shape == (2, 2)
