"""The experiment grid: every paper suite of every world in a cell, no duplicates, selection;
the estimates of GPU time; the paper's numbers as data."""

import pytest

from specrl_jax import specs
from specrl_jax.benchmark import estimate, grid, paper
from specrl_jax.benchmark.store import Store

PAPER_PREFIXES = ("letter/", "zone/", "arm_grippers/", "arm_grippers_arm/", "multi_agent_zone/")
WORLDS = {  # the paper's world -> the env IDs whose cells carry its suites
    "letter/": ("LetterLTL0-v0", "LetterLTL0-v0.partial"),
    "zone/": ("PointLTL0-v0", "PointLTL1-v0", "PointLTL2-v0", "CarLTL0-v0", "AntLTL0-v0",
              "PointLTL0Vision-v0", "CarLTL0Vision-v0", "AntLTL0Vision-v0"),
    "arm_grippers/": ("PandaLTLReach0Joints-v0",),
    "arm_grippers_arm/": ("PandaLTLReach1Joints-v0",),
    "multi_agent_zone/": ("PointLTL0MA2-v0",),
}


def test_every_paper_suite_of_every_world_is_in_a_cell_of_each_method():
    paper_suites = [s for s in specs.list_suites() if s.startswith(PAPER_PREFIXES)
                    and s.split("/")[1] in ("finite", "infinite") and s.count("/") == 2]
    assert len(paper_suites) == 22  # 4 letter, 5 zone, 5 + 2 arm, 6 multi-agent
    for prefix, envs in WORLDS.items():
        suites = [s for s in paper_suites if s.startswith(prefix)]
        for env_id in envs:
            cells = [c for c in grid.GRID if c.env_id == env_id]
            methods = grid.COORDINATOR_METHODS if prefix == "multi_agent_zone/" else grid.METHODS
            assert {c.method for c in cells} == set(methods), env_id
            for suite in suites:
                finite = "/finite/" in suite
                carriers = {c.method for c in cells if suite in c.suites}
                expected = set(methods) if finite else set(methods) - {"rad", "ltl2action"}
                assert expected <= carriers, (env_id, suite)
    assert all(set(c.suites) <= set(paper_suites) for c in grid.GRID)


def test_no_duplicate_cells_and_names_map_to_files_and_back():
    names = [c.name for c in grid.GRID]
    assert len(names) == len(set(names))
    for c in grid.GRID:
        assert grid.cell_name(grid.file_name(c.name)) == c.name
        assert "/" not in grid.file_name(c.name)
    assert grid.cell("LetterLTL0-v0/ltl2action+bootcamp").options()["encoder"].endswith(
        "baselines/data/ltl2action_encoder_letter.msgpack")
    assert [c.step for c in grid.GRID] == sorted(c.step for c in grid.GRID)  # the order


def test_selection_by_pattern_and_estimates():
    assert [c.name for c in grid.select("LetterLTL0-v0/genz")] == ["LetterLTL0-v0/genz"]
    arm = grid.select("Panda*/*")
    assert len(arm) == 10 and all(c.env_id.startswith("Panda") for c in arm)
    assert len(grid.select("LetterLTL0-v0/*,PointLTL0-v0/genz")) == 7
    with pytest.raises(ValueError, match="matches no cell"):
        grid.select("NoSuchWorld/*")
    with pytest.raises(ValueError, match="no cell"):
        grid.cell("LetterLTL0-v0/nope")


def test_estimates_come_from_the_rates_the_store_measured(tmp_path):
    rates = {"PointLTL0-v0/genz": 700e3, "PointLTL2-v0/genz": 740e3, "PointLTL2-v0/gcrl": 592e3,
             "CarLTL0-v0/genz": 190e3, "PointLTL0Vision-v0/deepltl": 66e3}
    # a measured cell: 5 x 15M over its own rate, plus set-up and evaluation
    point = grid.cell("PointLTL0-v0/genz")
    assert estimate.seconds(point, rates) == pytest.approx(
        75e6 / 700e3 + estimate.SETUP_S + estimate.EVAL_S["PointLTL0-v0"])
    # an unmeasured cell: its world's GenZ-LTL rate times the method's ratio on PointLTL2
    assert estimate.training_rate(grid.cell("CarLTL0-v0/gcrl"), rates) == pytest.approx(190e3 * 0.8)
    # a world without a trained cell: GenZ-LTL's profiled training rate there, else the env's
    # rate times the training-to-env ratio
    assert estimate.training_rate(grid.cell("AntLTL0-v0/gcrl"), rates) == pytest.approx(
        estimate.PROFILED_RATES["AntLTL0-v0"] * 0.8)
    no_car = {k: v for k, v in rates.items() if not k.startswith("CarLTL0-v0/")}
    assert estimate.training_rate(grid.cell("CarLTL0-v0/gcrl"), no_car) == pytest.approx(
        estimate.ENV_RATES["CarLTL0-v0"] * estimate.TRAIN_PER_ENV_STEP * 0.8)
    # an image cell trains at DeepLTL's image pace (every epoch); another robot adds its physics'
    # time per env step and its LiDAR world's evaluation time over Point's
    gcrl = grid.cell("PointLTL0Vision-v0/gcrl")
    assert estimate.training_rate(gcrl, rates) == 66e3
    car = grid.cell("CarLTL0Vision-v0/gcrl")
    assert estimate.training_rate(car, rates) < 66e3
    assert estimate.evaluation_seconds(car) == (estimate.EVAL_S["PointLTL0Vision-v0"]
                                                + estimate.EVAL_S["CarLTL0-v0"] - estimate.EVAL_S["PointLTL0-v0"])
    # the package's store: every trained cell's summary rate; every cell's estimate sane
    measured = estimate.measured_rates()
    assert measured["PointLTL0-v0/genz"] == Store().read(point)["training"]["env_steps_per_s"]
    assert all(0 < estimate.seconds(c, measured) < 3 * 24 * 3600 for c in grid.GRID)
    assert estimate.measured_rates(Store(tmp_path)) == {}


def test_paper_numbers_are_data_with_sources():
    numbers = paper.load()
    assert all(n.source for n in numbers)
    letter = paper.lookup("LetterLTL0-v0", "letter/finite/ind", "genz", "eta_s")
    assert letter.text() == "0.98 ± 0.03"
    assert paper.lookup("PointLTL0-v0", "zone/finite/ind", "ltl2action+bootcamp",
                        "eta_s").mean == 0.58  # a variant is compared with its method
    arm = paper.lookup("PandaLTLReach0Joints-v0", "arm_grippers/finite/ind", "gcrl", "eta_v")
    assert arm.mean == 0.10
    assert paper.lookup("CarLTL0-v0", "zone/finite/ind", "genz", "eta_s") is None
    names = {c.name for c in grid.GRID}
    for n in numbers:  # every number sits beside a cell of the grid
        assert f"{n.env}/{n.method}" in names and n.suite in grid.cell(f"{n.env}/{n.method}").suites


def test_image_cells_train_and_evaluate_on_the_64_pixel_camera():
    import specrl_jax
    from specrl_jax.benchmark import experiment

    vision = [c for c in grid.GRID if "Vision" in c.env_id]
    assert len(vision) == 15 and all(dict(c.env_options) == {"image_size": 64} for c in vision)
    assert all(not c.env_options for c in grid.GRID if "Vision" not in c.env_id)
    assert all(c.options()["image_dtype"] == "bfloat16" for c in vision)
    assert all("image_dtype" not in c.options() for c in grid.GRID if "Vision" not in c.env_id)
    world, _ = specrl_jax.make(vision[0].env_id, **dict(vision[0].env_options))
    assert world.observation_space.spaces["image"].shape == (64, 64, 3)
    assert experiment.family(vision[0].env_id) == experiment.family("PointLTL0-v0")
