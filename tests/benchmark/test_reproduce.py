"""`reproduce` on a scratch store with an injected training and evaluation (no JAX work): skip
done cells, resume an interrupted evaluation at the suites it lacks, retrain cells whose seeds are
incomplete; the committed store's states; `--list`."""

import dataclasses
import json
import shutil
import time
from concurrent.futures import Future

import numpy as np
import pytest

from specrl_jax import cli
from specrl_jax.benchmark import estimate, grid, reproduce
from specrl_jax.benchmark import store as store_lib
from specrl_jax.benchmark.store import Store, missing_work
from specrl_jax.eval.evaluate import EvalResult
from specrl_jax.eval.metrics import EpisodeTable
from specrl_jax.eval.report import SuiteResult

CELL = dataclasses.replace(grid.cell("LetterLTL0-v0/genz"), seeds=2, total_steps=2048, episodes=3)


def fake_result(cell, suite, success=0.75, seeds=None):
    seeds = list(seeds or range(1, cell.seeds + 1))
    specs, episodes = 2, cell.episodes
    rng = np.random.default_rng(len(suite))  # seed s's episodes whatever the other seeds
    shape, rows = (max(seeds), specs, episodes), np.array(seeds) - 1
    ok = (rng.random(shape) < success)[rows]
    table = EpisodeTable(ok, ~ok & (rng.random(shape) < 0.5)[rows], np.full(ok.shape, 7),
                         ok.astype(int), np.zeros(ok.shape, bool))
    finite = "/finite/" in suite
    result = EvalResult(cell.env_id, ("F a", "F b"), np.array([finite, finite]),
                        tuple(seeds), episodes, 75 if finite else 750, table)
    return SuiteResult(cell.env_id, suite, "GenZ-LTL", result)


class Clock:
    """`reproduce`'s clock, which moves only when a fake training says so: a time limit's test
    then does not depend on how fast the machine running it is."""
    perf_counter = staticmethod(time.perf_counter)
    sleep = staticmethod(time.sleep)

    def __init__(self):
        self.now = 1000.0

    def monotonic(self):
        return self.now


class Fakes:
    def __init__(self, fail_on=None, train_s=0.0, clock=None):
        self.trained, self.evaluated, self.fail_on, self.train_s = 0, [], fail_on, train_s
        self.clock = clock
        self.seeds = []
        self.limits = []

    def train(self, cell, run_dir, log, max_wall_s=None, on_compiled=None, seeds=None):
        """Completes unless given no time (`max_wall_s` 0): then it stops after its first update,
        as the real training stops at its first checkpoint. Seed s's curve succeeds at rate
        s * update / 10."""
        seeds = list(seeds or range(1, cell.seeds + 1))
        self.trained += 1
        self.seeds.append(seeds)
        if on_compiled is not None:
            on_compiled()
        self.limits.append(max_wall_s)
        if self.clock is not None:
            self.clock.now += self.train_s
        else:
            time.sleep(self.train_s)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "params.msgpack").write_bytes(b"")
        rows = [{"update": u, "env_steps": 1024 * u, "wall_s": float(u),
                 "success_rate": float(np.mean([s * u / 10 for s in seeds])),
                 "success_rate_seeds": [s * u / 10 for s in seeds]} for u in (1, 2)]
        (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
        params = {"w": np.zeros((len(seeds), 3), np.float32)}
        return params, {"complete": max_wall_s != 0.0, "env_steps_per_seed": cell.total_steps,
                        "num_seeds": len(seeds), "env_steps_per_s": 1000.0}

    def evaluate(self, cell, params, suites, log, seeds=None):
        if self.fail_on in suites:
            raise RuntimeError("interrupted")
        self.evaluated += suites
        return [fake_result(cell, suite, seeds=seeds) for suite in suites]

    def load(self, cell, path, num_seeds):
        return {"w": np.zeros((num_seeds, 3), np.float32)}

    def run(self, store):
        return reproduce.run_cell(CELL, store, log=lambda line: None, train=self.train,
                                  evaluate=self.evaluate, load=self.load, trajectories=False)


def test_a_cell_is_trained_evaluated_then_skipped(tmp_path):
    store = Store(tmp_path)
    assert store.state(CELL) == "missing"
    fakes = Fakes()
    record = fakes.run(store)
    assert fakes.trained == 1 and fakes.evaluated == list(CELL.suites)
    assert record["state"] == "done" and store.state(CELL) == "done"
    assert sorted(record["suites"]) == sorted(CELL.suites)
    entry = record["suites"]["letter/finite/ind"]
    assert entry["seeds"] == [1, 2] and np.shape(entry["per_seed"]["eta_s"]) == (2, 2)
    assert "episodes" not in entry  # per-episode tables are not kept
    assert store.params_path(CELL).exists() and store.curve_path(CELL).exists()
    assert record["wall_s"]["train"] == pytest.approx(2 * 2048 / 1000.0)
    again = Fakes()
    assert again.run(store)["state"] == "done"
    assert again.trained == 0 and again.evaluated == []
    states = reproduce.reproduce(cells=[CELL], store=store, gpus=1, log=lambda line: None,
                                 train=again.train, evaluate=again.evaluate, load=again.load)
    assert states == {CELL.name: "done"} and again.trained == 0


def test_the_evaluator_compiled_beside_training_scores_the_trained_cell(tmp_path):
    fakes, asked = Fakes(), []

    def prepare(cell, suites, log, seeds):  # its future holds the evaluation of every suite
        asked.append(list(suites))

        def evaluator(params):
            asked.append("used")
            return fakes.evaluate(cell, params, suites, log, seeds=seeds)

        future = Future()
        future.set_result(evaluator)
        return future

    store = Store(tmp_path)
    record = reproduce.run_cell(CELL, store, log=lambda line: None, train=fakes.train,
                                evaluate=fakes.evaluate, load=fakes.load, trajectories=False,
                                prepare=prepare)
    assert record["state"] == "done" and asked == [list(CELL.suites), "used"]
    assert fakes.evaluated == list(CELL.suites)  # once, through the prepared evaluator
    three, asked[:] = dataclasses.replace(CELL, seeds=3), []  # a part's evaluator: its seeds
    record = reproduce.run_cell(three, store, log=lambda line: None, train=fakes.train,
                                evaluate=fakes.evaluate, load=fakes.load, trajectories=False,
                                prepare=prepare, part=[3])
    assert asked == [list(CELL.suites), "used"]
    assert record["suites"]["letter/finite/ind"]["seeds"] == [1, 2, 3]
    failing = Fakes()  # a failed background compilation: evaluated the usual way

    def broken(cell, suites, log, seeds):
        future = Future()
        future.set_exception(RuntimeError("out of memory"))
        return future

    lines = []
    record = reproduce.run_cell(CELL, Store(tmp_path / "b"), log=lines.append,
                                train=failing.train, evaluate=failing.evaluate, load=failing.load,
                                trajectories=False, prepare=broken)
    assert record["state"] == "done" and failing.evaluated == list(CELL.suites)
    assert any("compiling the evaluator beside training failed (RuntimeError: out of memory)"
               in line for line in lines)
    raising = Fakes()  # failing before its thread starts: the training goes on

    def unbuildable(cell, suites, log, seeds):
        raise ValueError("no such world")

    lines.clear()
    record = reproduce.run_cell(CELL, Store(tmp_path / "c"), log=lines.append,
                                train=raising.train, evaluate=raising.evaluate, load=raising.load,
                                trajectories=False, prepare=unbuildable)
    assert record["state"] == "done" and raising.evaluated == list(CELL.suites)
    assert any("the evaluator will compile after training (ValueError: no such world)" in line
               for line in lines)


def test_an_interrupted_evaluation_resumes_at_the_missing_suites(tmp_path):
    store = Store(tmp_path)
    first = Fakes(fail_on="letter/infinite/rsp")
    with pytest.raises(RuntimeError, match="interrupted"):
        first.run(store)
    assert first.trained == 1 and first.evaluated == []  # every suite in one evaluation
    assert store.state(CELL) == "partial"
    assert missing_work(CELL, store.read(CELL)) == list(CELL.suites)
    second = Fakes()
    assert second.run(store)["state"] == "done"
    assert second.trained == 0  # the run directory's parameters are reused
    assert second.evaluated == list(CELL.suites)
    record = store.read(CELL)  # a record missing two suites (e.g. a suite's version changed)
    for suite in ("letter/infinite/rsp", "letter/infinite/rec"):
        del record["suites"][suite]
    store.write(CELL, record)
    third = Fakes()
    assert third.run(store)["state"] == "done"
    assert third.trained == 0 and third.evaluated == ["letter/infinite/rsp", "letter/infinite/rec"]


def test_a_stored_cell_is_evaluated_with_the_options_it_was_trained_with(tmp_path):
    """The grid may change a cell's options after it was trained (the image cells' bfloat16
    convolutions): its stored parameters are re-scored, loaded and evaluated as trained."""
    store = Store(tmp_path)
    Fakes().run(store)
    now = dataclasses.replace(CELL, method_options=(("image_dtype", "bfloat16"),))
    assert store.trained_as(now) == CELL and store.trained_as(CELL) == CELL
    assert Store(tmp_path / "empty").trained_as(now) == now  # nothing trained: the grid's
    record = store.read(CELL)
    del record["suites"]["letter/infinite/rsp"]  # a suite to score again
    store.write(CELL, record)
    seen = []
    fakes = Fakes()
    evaluate = fakes.evaluate
    fakes.evaluate = lambda cell, *rest, **kw: (seen.append(cell.options())
                                                or evaluate(cell, *rest, **kw))
    reproduce.run_cell(now, store, log=lambda line: None, train=fakes.train,
                       evaluate=fakes.evaluate, load=fakes.load, trajectories=False)
    assert fakes.trained == 0 and seen == [{}]
    assert store.read(CELL)["config"]["method_options"] == {}
    # without its parameters the cell trains again from nothing, with the grid's options
    reproduce.discard(CELL, store)
    Fakes().run(store)
    shutil.rmtree(store.scratch_dir(CELL))
    store.params_path(CELL).unlink()
    record = store.read(CELL)
    del record["suites"]["letter/infinite/rsp"]
    store.write(CELL, record)
    seen.clear()
    reproduce.run_cell(now, store, log=lambda line: None, train=fakes.train,
                       evaluate=fakes.evaluate, load=fakes.load, trajectories=False)
    assert fakes.trained == 1 and seen == [{"image_dtype": "bfloat16"}]
    assert store.read(CELL)["config"]["method_options"] == {"image_dtype": "bfloat16"}


def test_a_time_limit_stops_training_and_evaluation_and_the_same_call_resumes(tmp_path,
                                                                               monkeypatch):
    clock = Clock()
    monkeypatch.setattr(reproduce, "time", clock)
    store = Store(tmp_path)
    other = dataclasses.replace(grid.cell("LetterLTL0-v0/rad"), seeds=2, total_steps=2048,
                                episodes=3)
    out_of_time = Fakes()  # the deadline is now: one update, checkpointed, then stop
    reproduce.run_cell(CELL, store, log=lambda line: None, train=out_of_time.train,
                       evaluate=out_of_time.evaluate, load=out_of_time.load, trajectories=False,
                       deadline=clock.now)
    assert out_of_time.limits == [0.0] and out_of_time.evaluated == []
    assert store.state(CELL) == "partial" and not store.read(CELL)["training"]["complete"]
    assert not store.params_path(CELL).exists()  # a stopped training's are not the method's yet
    # trains to the end but past the limit: no evaluation, no next cell
    slow = Fakes(train_s=0.5, clock=clock)
    lines = []
    states = reproduce.reproduce(cells=[CELL, other], store=store, gpus=1, log=lines.append,
                                 max_minutes=0.2 / 60, train=slow.train, evaluate=slow.evaluate,
                                 load=slow.load, trajectories=False)
    assert states == {CELL.name: "partial", other.name: "missing"}
    assert slow.trained == 1 and slow.limits[0] == pytest.approx(0.2) and slow.evaluated == []
    assert store.params_path(CELL).exists()
    assert any("time limit reached before evaluating" in line for line in lines)
    assert any(f"{other.name} not started" in line for line in lines)
    rest = Fakes()
    assert reproduce.reproduce(cells=[CELL], store=store, gpus=1, log=lambda line: None,
                               train=rest.train, evaluate=rest.evaluate, load=rest.load,
                               trajectories=False) == {CELL.name: "done"}
    assert rest.trained == 0 and rest.evaluated == list(CELL.suites)  # its parameters reused


def test_an_evaluation_that_would_outrun_the_time_left_waits_for_the_next_call(tmp_path,
                                                                               monkeypatch):
    clock = Clock()
    monkeypatch.setattr(reproduce, "time", clock)
    store = Store(tmp_path)
    needs = estimate.evaluation_seconds(CELL)
    fakes, lines = Fakes(), []
    reproduce.run_cell(CELL, store, log=lines.append, train=fakes.train, evaluate=fakes.evaluate,
                       load=fakes.load, trajectories=False, deadline=clock.now + needs / 2)
    assert fakes.trained == 1 and fakes.evaluated == [] and store.state(CELL) == "partial"
    assert any("time limit reached before evaluating" in line for line in lines)
    reproduce.run_cell(CELL, store, log=lines.append, train=fakes.train, evaluate=fakes.evaluate,
                       load=fakes.load, trajectories=False, deadline=clock.now + needs * 1.5)
    assert fakes.trained == 1 and fakes.evaluated == list(CELL.suites)
    assert store.state(CELL) == "done"


def test_a_failing_cell_is_logged_and_the_next_one_runs(tmp_path):
    store = Store(tmp_path)
    other = dataclasses.replace(grid.cell("LetterLTL0-v0/rad"), seeds=2, total_steps=2048,
                                episodes=3)
    fakes = Fakes()

    def train(cell, *args, **kwargs):
        if cell.name == CELL.name:
            raise ValueError("checkpoint x cannot be read")
        return fakes.train(cell, *args, **kwargs)

    lines = []
    states = reproduce.reproduce(cells=[CELL, other], store=store, gpus=1, log=lines.append,
                                 train=train, evaluate=fakes.evaluate, load=fakes.load,
                                 trajectories=False)
    assert states == {CELL.name: "missing", other.name: "done"}
    failed = next(line for line in lines if "failed" in line)
    assert failed.startswith(f"[{CELL.name}] failed, missing: ValueError: checkpoint x cannot")
    assert "Traceback" in failed


def test_a_cell_with_fewer_seeds_is_retrained_and_all_suites_reevaluated(tmp_path):
    store = Store(tmp_path)
    one_seed = dataclasses.replace(CELL, seeds=1)
    fakes = Fakes()
    reproduce.run_cell(one_seed, store, log=lambda line: None, train=fakes.train,
                       evaluate=fakes.evaluate, load=fakes.load)
    assert store.state(one_seed) == "done" and store.state(CELL) == "partial"
    (store.scratch_dir(CELL) / "run" / "params.msgpack").unlink()  # that run is gone
    fakes = Fakes()
    assert fakes.run(store)["state"] == "done"
    assert fakes.trained == 1 and fakes.evaluated == list(CELL.suites)



def test_the_trajectory_figure_follows_the_stored_parameters(tmp_path):
    """A Zone cell draws its figure's episodes once with its seed-1 parameters; a done cell
    whose episodes are missing draws them from the stored parameters without training or
    evaluating; a retrained cell draws them again from its new parameters."""
    store = Store(tmp_path)
    point = dataclasses.replace(grid.cell("PointLTL0-v0/genz"), seeds=2, total_steps=2048,
                                episodes=3)
    drawn = []

    def recorder(cell, params):
        drawn.append(np.shape(params["w"]))
        return {"formula": "F blue", "drawing": len(drawn)}

    def run(fakes):
        return reproduce.run_cell(point, store, log=lambda line: None, train=fakes.train,
                                  evaluate=fakes.evaluate, load=fakes.load, trajectories=recorder)

    def stored():
        return json.loads(store.trajectories_path(point).read_text())["drawing"]

    first = Fakes()
    assert run(first)["state"] == "done"
    assert drawn == [(2, 3)] and stored() == 1  # the training's parameters, every seed
    again = Fakes()
    run(again)
    assert len(drawn) == 1 and again.trained == 0  # done, and its episodes are there
    store.trajectories_path(point).unlink()
    missing = Fakes()
    assert run(missing)["state"] == "done"
    assert drawn[-1] == (1, 3) and stored() == 2  # the stored seed-1 parameters
    assert missing.trained == 0 and missing.evaluated == []
    record = store.read(point)
    record["training"]["complete"] = False  # an unfinished training: it trains again
    store.write(point, record)
    retrained = Fakes()
    assert run(retrained)["state"] == "done"
    assert retrained.trained == 1 and drawn[-1] == (2, 3) and stored() == 3

def test_the_committed_store_and_the_list(capsys):
    store = Store()
    assert store.state(grid.cell("LetterLTL0-v0/genz")) == "done"
    assert store.state(grid.cell("PointLTL0MA2-v0/deepltl+coordinator")) == "done"
    for name in store.names():  # every stored cell is a grid cell, and done ones have all suites
        c = grid.cell(name)
        assert store.read(c)["cell"] == name
    chosen = grid.select("LetterLTL0-v0/*,Panda*/genz")
    states = {c.name: store.state(c) for c in chosen}
    assert cli.main(["reproduce", "--list", "--cells", "LetterLTL0-v0/*,Panda*/genz"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split()[2].rstrip("*") for line in out.splitlines()
            if line.split() and line.split()[0] in states}
    assert rows == states  # the list shows each cell's state in the store (* legacy settings)
    done = sum(s == "done" for s in states.values())
    assert done >= 6 and f"{len(chosen)} cells: {done} done, {len(chosen) - done} to run" in out
    assert reproduce.reproduce("LetterLTL0-v0/genz", store=store, log=print) == {
        "LetterLTL0-v0/genz": "done"}  # done: nothing is trained
    assert "done, skipped" in capsys.readouterr().out


def test_several_gpus_run_one_cell_per_gpu_side_by_side(tmp_path, monkeypatch):
    launched = []

    class FakeProcess:  # a worker that finishes at once, having written nothing
        def __init__(self, cmd, env, **kw):
            launched.append((cmd, env["CUDA_VISIBLE_DEVICES"]))
            self.stdout, self.returncode = iter(["worker line\n"]), 0

        def poll(self):
            return 0

    monkeypatch.setattr(reproduce.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(reproduce.time, "sleep", lambda s: None)
    cells = grid.select("PointLTL1-v0/*")[:3]
    lines = []
    states = reproduce.reproduce(cells=cells, store=Store(tmp_path), gpus=2, log=lines.append,
                                 worker_args=["--seeds", "1"])
    assert states == {c.name: "missing" for c in cells}
    assert [gpu for _, gpu in launched] == ["0", "1", "0"]
    for (cmd, _), c in zip(launched, cells):
        assert cmd[1:] == ["-m", "specrl_jax.benchmark.reproduce", "--cells", c.name, "--store",
                           str(tmp_path), "--gpus", "1", "--seeds", "1"]
    assert any("3/3 cells" in line and "ETA" in line for line in lines)
    # a time limit: each worker is given the minutes left; none starts once they are spent
    launched.clear()
    reproduce.reproduce(cells=cells, store=Store(tmp_path), gpus=2, log=lines.append,
                        max_minutes=5)
    assert len(launched) == 3
    for cmd, _ in launched:
        assert cmd[-2] == "--max-minutes" and 4.9 < float(cmd[-1]) <= 5.0
    launched.clear()
    reproduce.reproduce(cells=cells, store=Store(tmp_path), gpus=2, log=lines.append,
                        max_minutes=1e-9)
    assert launched == [] and "not started" in lines[-1]


def test_cells_per_gpu_share_each_gpu_and_split_its_memory(tmp_path, monkeypatch):
    launched, alive = [], []

    class FakeProcess:  # a worker that runs until it has been polled twice
        def __init__(self, cmd, env, **kw):
            alive.append(self)
            launched.append((env["CUDA_VISIBLE_DEVICES"],
                             env.get("XLA_PYTHON_CLIENT_MEM_FRACTION"), len(alive)))
            self.stdout, self.returncode, self.polls = iter([]), None, 0

        def poll(self):
            self.polls += 1
            if self.polls == 2:
                alive.remove(self)
                self.returncode = 0
            return self.returncode

    monkeypatch.setattr(reproduce.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(reproduce.time, "sleep", lambda s: None)
    monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION", raising=False)
    cells = grid.select("PointLTL1-v0/*")[:5]
    lines = []
    reproduce.reproduce(cells=cells, store=Store(tmp_path), gpus=1, cells_per_gpu=2,
                        log=lines.append)
    assert [gpu for gpu, _, _ in launched] == ["0"] * 5
    assert {share for _, share, _ in launched} == {"0.375"}  # JAX's default 0.75, halved
    assert max(running for *_, running in launched) == 2
    assert "2 side by side on 1 GPU" in lines[0]
    launched.clear()
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.9")
    reproduce.reproduce(cells=cells, store=Store(tmp_path), gpus=2, cells_per_gpu=3,
                        log=lines.append)
    assert [gpu for gpu, _, _ in launched] == ["0", "1", "0", "1", "0"]  # each GPU in turn
    assert {share for _, share, _ in launched} == {"0.300"}
    assert max(running for *_, running in launched) == 5
    with pytest.raises(ValueError, match="cells_per_gpu is a count"):
        reproduce.reproduce(cells=cells, store=Store(tmp_path), gpus=1, cells_per_gpu=0)


def test_rerun_discards_a_done_cell_and_runs_it_end_to_end(tmp_path):
    store = Store(tmp_path)
    Fakes().run(store)
    assert store.state(CELL) == "done"
    fakes = Fakes()
    states = reproduce.reproduce(cells=[CELL], store=store, gpus=1, log=lambda line: None,
                                 rerun=True, train=fakes.train, evaluate=fakes.evaluate,
                                 load=fakes.load)
    assert states == {CELL.name: "done"}
    assert fakes.trained == 1 and fakes.evaluated == list(CELL.suites)


def test_seeds_trained_in_parts_get_the_keys_of_one_training_of_them_all():
    import jax

    from specrl_jax.baselines.runs import seed_keys

    key = jax.random.key(7)
    whole = jax.random.key_data(seed_keys(key, 5))
    np.testing.assert_array_equal(jax.random.key_data(seed_keys(key, 2)), whole[:2])
    np.testing.assert_array_equal(jax.random.key_data(seed_keys(key, 3, first_seed=3)), whole[2:])
    with pytest.raises(ValueError, match="numbered from 1"):
        seed_keys(key, 2, first_seed=0)


def test_a_cell_completed_in_parts_equals_its_seeds_side_by_side(tmp_path):
    three = dataclasses.replace(CELL, seeds=3)
    store, fakes = Store(tmp_path / "parts"), Fakes()

    def run(store, part=None, fakes=fakes):
        return reproduce.run_cell(three, store, log=lambda line: None, train=fakes.train,
                                  evaluate=fakes.evaluate, load=fakes.load, trajectories=False,
                                  part=part)

    first = run(store, [1])
    assert first["state"] == "partial" and store.params_path(three).exists()
    assert missing_work(three, first, [1]) == [] and missing_work(three, first) == [
        "train", *three.suites]
    assert first["suites"]["letter/finite/ind"]["seeds"] == [1]
    done = run(store, range(2, 4))
    assert done["state"] == "done" and fakes.seeds == [[1], [2, 3]]
    assert done["training"]["complete"] and sorted(done["training"]["parts"]) == ["1-1", "2-3"]
    assert done["wall_s"]["train"] == pytest.approx(3 * 2048 / 1000.0)
    assert run(store, [2, 3])["state"] == "done" and fakes.trained == 2  # nothing left to do
    # the same cell trained and evaluated side by side gives the same record and curve
    together = Store(tmp_path / "together")
    whole = run(together, fakes=Fakes())
    for suite in three.suites:
        a, b = done["suites"][suite], whole["suites"][suite]
        assert a["seeds"] == b["seeds"] == [1, 2, 3]
        assert a["per_seed"] == b["per_seed"] and a["summary"] == b["summary"]
    curve = [json.loads(line) for line in store.curve_path(three).read_text().splitlines()]
    expected = [json.loads(line) for line in together.curve_path(three).read_text().splitlines()]
    for row, want in zip(curve, expected, strict=True):
        assert row["success_rate_seeds"] == want["success_rate_seeds"]
        assert row["success_rate"] == pytest.approx(want["success_rate"])
        assert row["wall_s"] == 2 * want["wall_s"]  # the parts' training times add up
    with pytest.raises(ValueError, match="not a part of its training"):
        run(store, [2, 4])
    with pytest.raises(ValueError, match="share seeds with the part 1-1"):
        run(store, [1, 2])
    states = reproduce.reproduce(cells=[three], store=store, gpus=1, log=lambda line: None,
                                 part=[1, 2], train=fakes.train, evaluate=fakes.evaluate,
                                 load=fakes.load, trajectories=False)
    assert states == {three.name: "done"} and fakes.trained == 2  # skipped, the store unchanged


def test_a_part_completes_a_stored_cell_of_fewer_seeds(tmp_path):
    store = Store(tmp_path)
    one_seed, three = dataclasses.replace(CELL, seeds=1), dataclasses.replace(CELL, seeds=3)
    fakes = Fakes()
    reproduce.run_cell(one_seed, store, log=lambda line: None, train=fakes.train,
                       evaluate=fakes.evaluate, load=fakes.load, trajectories=False)
    record = reproduce.run_cell(three, store, log=lambda line: None, train=fakes.train,
                                evaluate=fakes.evaluate, load=fakes.load, trajectories=False,
                                part=[2, 3])
    assert record["state"] == "done" and fakes.seeds == [[1], [2, 3]]
    assert sorted(record["training"]["parts"]) == ["1-1", "2-3"]
    assert record["training"]["seeds"] == [1, 2, 3]
    assert record["suites"]["letter/finite/ood"]["seeds"] == [1, 2, 3]
    assert "eval" in record["wall_s"]  # the first part's evaluation time is kept


def test_the_list_estimates_a_partial_cell_by_the_seeds_it_lacks(tmp_path):
    long = dataclasses.replace(CELL, seeds=3, total_steps=10**9)  # training dominates
    store, fakes = Store(tmp_path), Fakes()
    reproduce.run_cell(long, store, log=lambda line: None, train=fakes.train,
                       evaluate=fakes.evaluate, load=fakes.load, trajectories=False, part=[1])
    (row, total) = reproduce.format_list([long], store).splitlines()[1:]
    rates = estimate.measured_rates()
    left = reproduce._duration(estimate.seconds(dataclasses.replace(long, seeds=2), rates))
    assert row.split()[2:] == ["partial", "1/3", *left.split()]
    assert left != reproduce._duration(estimate.seconds(long, rates)) and left in total


def test_parts_trained_with_other_settings_are_not_merged():
    held = {"num_seeds": 2, "complete": True, "ppo": {"num_envs": 512, "lr": 3e-4},
            "env_steps_per_seed": 100, "env_steps_per_s": 10.0}
    part = {"seeds": [3], "complete": True, "ppo": {"num_envs": 16, "lr": 3e-4},
            "env_steps_per_seed": 100, "env_steps_per_s": 5.0}
    with pytest.raises(ValueError, match="other ppo than the held seeds 1-2"):
        store_lib.merge_training(held, part, 3)
    newer = {"num_envs": 512, "lr": 3e-4, "update_epochs": 10,  # fields added since
             "entropy_per_action_dim": False}  # (as the held part trained)
    merged = store_lib.merge_training(held, {**part, "ppo": newer}, 3)
    assert merged["complete"] and merged["seeds"] == [1, 2, 3] and merged["num_seeds"] == 3
    assert merged["ppo"] == newer  # the settings as the code writes them now
    # a setting the held part predates counts as it trained: the entropy summed over dimensions
    with pytest.raises(ValueError, match="other ppo than the held seeds 1-2"):
        store_lib.merge_training(held, {**part, "ppo": {**newer, "entropy_per_action_dim": True}},
                                 3)
    assert merged["env_steps_per_s"] == pytest.approx(300 / (200 / 10.0 + 100 / 5.0))


def test_a_stopped_part_joins_the_held_seeds_until_it_resumes():
    held = {"num_seeds": 2, "complete": True, "ppo": {"num_envs": 512},
            "env_steps_per_seed": 100, "env_steps_per_s": 10.0}
    stopped = {"seeds": [3], "complete": False, "ppo": {"num_envs": 512},
               "env_steps_per_seed": 40, "env_steps_per_s": 5.0}
    merged = store_lib.merge_training(held, stopped, 3)
    assert not merged["complete"] and merged["seeds"] == [1, 2]
    assert merged["env_steps_per_seed"] == 100  # the trained seeds', not the stopped part's
    with pytest.raises(ValueError, match="other env_steps_per_seed than the held seeds 1-2"):
        store_lib.merge_training(held, {**stopped, "complete": True}, 3)


@pytest.mark.parametrize("text", ["0-2", "3-1", "two", "1-"])
def test_a_seed_range_that_is_not_one_is_refused(text, capsys):
    with pytest.raises(SystemExit):
        cli.main(["reproduce", "--seed-range", text, "--list"])
    assert "is not a seed range" in capsys.readouterr().err


def test_an_interrupted_part_resumes_and_its_curve_joins_once_complete(tmp_path):
    store, three = Store(tmp_path), dataclasses.replace(CELL, seeds=3)
    fakes = Fakes()

    def run(part, limit=None):
        return reproduce.run_cell(three, store, log=lambda line: None, train=fakes.train,
                                  evaluate=fakes.evaluate, load=fakes.load, trajectories=False,
                                  part=part, deadline=limit)

    run([1])
    held = store.curve_path(three).read_text()
    stopped = run([2, 3], limit=time.monotonic() - 1)  # no time: stops after its first update
    assert stopped["state"] == "partial" and not stopped["training"]["complete"]
    assert store.curve_path(three).read_text() == held  # seed 1's curve alone until then
    assert run([2, 3])["state"] == "done"
    rows = [json.loads(line) for line in store.curve_path(three).read_text().splitlines()]
    assert [len(r["success_rate_seeds"]) for r in rows] == [3, 3]
