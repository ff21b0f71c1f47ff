"""benchmarks/train_profile.py runs at a tiny size on the CPU and its row adds up.

One fresh process profiles GenZ-LTL on LetterLTL0-v0 (1 seed, 2 x 4 envs x 16 steps, 2 minibatches,
1 epoch, so that every update runs the same epochs, a reset bank of 16 layouts) with the env
batch sharded over two forced CPU devices, as training shards it: the row has the harness's keys
and the profile's, every time and rate is positive and finite, and the rollout plus the update
(timed apart) come close to the training's own full step, and both programs are data parallel
(no gathers in the rollout, the gradients summed across devices), and the profiler's kernel list
is the programs' own instructions. The weak-scaling efficiency is checked as a function.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "train_profile.py"
ARGS = ["--env", "LetterLTL0-v0", "--method", "genz", "--seeds", "1", "--num-envs", "4",
        "--num-steps", "16", "--minibatches", "2", "--epochs", "1", "--updates", "1",
        "--repeats", "2", "--map-bank", "16", "--devices", "2", "--kernels", "4"]
ROW_KEYS = {"figure", "value", "device", "batch", "versions", "date", "command"}
PARTS = ("rollout", "update", "full")


def test_train_profile_runs_tiny_and_its_parts_add_up(tmp_path):
    out = tmp_path / "rows.json"
    flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    env = dict(os.environ, JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"), XLA_FLAGS=flags)
    done = subprocess.run([sys.executable, str(SCRIPT), *ARGS, "--out", str(out)], check=False,
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    assert "rollout share" in done.stdout  # the human table
    (row,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert ROW_KEYS <= set(row)
    assert (row["env"], row["method"], row["seeds"], row["batch"]) == ("LetterLTL0-v0", "genz", 1, 8)
    assert (row["num_envs"], row["num_steps"], row["num_minibatches"]) == (8, 16, 2)
    assert row["minibatch_size"] == 64 and row["map_bank"] == 16 and row["devices"] == 2
    for part in PARTS:
        for key in (f"{part}_s", f"{part}_steps_per_s"):
            assert math.isfinite(row[key]) and row[key] > 0, (key, row[key])
        assert row[f"{part}_steps_per_s"] * row[f"{part}_s"] == pytest.approx(8 * 16)
        assert row["compile_s"][part] > 0
        program = row["programs"][part]
        assert program["hlo_instructions"] > program["fusions"] > 0
        assert program["host_transfers"] == 0  # the trainer logs nothing by default
    assert row["epochs_per_seed"] == [1] and row["full_epochs_per_seed"] == [[1]]
    assert row["grad_steps_per_update"] == 2 and row["grad_steps_per_s"] > 0
    # one epoch, so the parts' epochs are the full step's: their sum is close to it (a loaded
    # 2-core CPU times loosely)
    assert row["split_s"] == pytest.approx(row["rollout_s"] + row["update_s"])
    assert 0.5 < row["full_s"] / row["split_s"] < 2.0, (row["full_s"], row["split_s"])
    assert 0 < row["rollout_share"] < 1
    # the KL stop's loop has no known trip count: a GPU syncs once per epoch and once to stop
    assert row["programs"]["update"]["while_loops_unknown_trip_count"] >= 1
    assert any("ppo/train.py" in where for where in row["programs"]["update"]["while_loop_sources"])
    assert row["host_syncs_per_update_min"] >= 2
    assert row["host_per_chunk"]["checkpoint_bytes"] > 0
    # data parallel over the two devices: the rollout steps each device's envs where they are, and
    # the update sums the minibatch gradients over the devices (an all-reduce) rather than
    # gathering the minibatches so that every device computes the whole update
    assert row["programs"]["rollout"]["collectives"] == {}
    assert row["programs"]["update"]["collectives"].get("all-reduce", 0) >= 1
    # the profiler's kernels: the longest of each part, HLO instructions of its program; the CPU's
    # loops are left out, so the kernels of two devices sum to at most twice the part's time (a
    # loaded CPU times loosely: 4x slack)
    for part in ("rollout", "update"):
        kernels = row["kernels"][part]
        assert len(kernels["top"]) == 4 and kernels["launches"] >= sum(n for _, _, n in kernels["top"])
        assert all(ms > 0 and not name.startswith("while") for name, ms, _ in kernels["top"])
        times = [ms for _, ms, _ in kernels["top"]]
        assert times == sorted(times, reverse=True)
        assert 0 < kernels["kernel_ms"] < 4 * 2 * 1e3 * row[f"{part}_s"]
    assert "kernel launches" in done.stdout


def test_train_profile_times_seeds_learning_in_turn(tmp_path):
    out = tmp_path / "rows.json"
    args = [*ARGS[:ARGS.index("--devices")], "--seeds", "2", "--learn-in-turn", "on",
            "--method-option", "image_dtype=float32", "--out", str(out)]
    env = dict(os.environ, JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
    done = subprocess.run([sys.executable, str(SCRIPT), *args], check=False, cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    (row,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert row["learn_in_turn"] and row["seeds"] == 2
    assert row["method_options"] == {"image_dtype": "float32"}
    assert row["epochs_per_seed"] == [1, 1] and row["full_epochs_per_seed"] == [[1], [1]]
    assert all(row[f"{part}_s"] > 0 for part in PARTS)


def test_weak_scaling_efficiency_is_the_rate_over_the_first_count_scaled(monkeypatch):
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import train_profile

    scaling = train_profile.efficiencies({1: 100.0, 2: 180.0, 4: 400.0})
    assert scaling == pytest.approx({1: 1.0, 2: 0.9, 4: 1.0})
    assert train_profile.efficiencies({2: 100.0, 4: 150.0}) == pytest.approx({2: 1.0, 4: 0.75})


def test_scaling_plot_draws_profile_rows_and_refuses_none(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import train_profile

    rows = [{"env": "LetterLTL0-v0", "method": "genz", "devices": n, "rollout_s": 0.07,
             "full_s": 0.12 + 0.08 * (n - 1), "full_steps_per_s": 1.4e6 * n * (1.2 - 0.2 * n)}
            for n in (1, 2)]
    rows.append({"figure": "Training weak scaling", "rates": {1: 1.0, 2: 1.8}})  # not a profile
    train_profile.plot_scaling(rows, str(tmp_path / "scaling.png"))
    assert (tmp_path / "scaling.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="no profile rows"):
        train_profile.plot_scaling(rows[2:], str(tmp_path / "none.png"))


def test_kernels_of_a_gpu_trace_are_the_stream_kernels_without_copies(monkeypatch):
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import train_profile

    meta = [("process_name", 1, None, "/host:CPU"), ("process_name", 2, None, "/device:GPU:0"),
            ("thread_name", 2, 7, "Stream #7(Compute,MemcpyD2H)"), ("thread_name", 2, 9, "CUPTI overhead")]
    events = [{"ph": "M", "name": kind, "pid": pid, "tid": tid, "args": {"name": name}}
              for kind, pid, tid, name in meta]
    spans = [(2, 7, "loop_add_fusion", 30.0, {}), (2, 7, "loop_add_fusion", 10.0, {}),
             (2, 7, "sm90_gemm", 50.0, {"hlo_op": "dot.3"}), (2, 7, "MemcpyD2H", 5.0, {}),
             (2, 9, "overhead", 99.0, {}), (1, 1, "PjitFunction", 500.0, {})]
    events += [{"ph": "X", "pid": pid, "tid": tid, "name": name, "dur": dur, "args": args}
               for pid, tid, name, dur, args in spans]
    monkeypatch.setattr(train_profile, "profiler_events", lambda fn: events)
    kernels = train_profile.kernel_times(lambda: None, None, 5)
    assert kernels == {"kernel_ms": 0.09, "launches": 3,
                       "top": [["dot.3", 0.05, 1], ["loop_add_fusion", 0.04, 2]]}
