"""Named suites: complete, parseable, satisfiable in their world, deterministic grid."""

from importlib import resources

import pytest
import spot
import yaml
from spec_spot_helpers import reach_avoid_chain, reach_only_chain

from specrl_jax import specs
from specrl_jax.specs import suites

REFERENCE = "/work/shared/reference/paper_specs.yaml"


def _paper_lists(tree, prefix=()):
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from _paper_lists(value, prefix + (key,))
        else:
            yield prefix + (key,), value


def test_every_paper_list_is_a_suite_with_the_same_formulas():
    with resources.files("specrl_jax.specs").joinpath("data", "paper_specs.yaml").open() as f:
        ours = yaml.safe_load(f)
    lists = list(_paper_lists(ours))
    assert len(lists) == 30
    for path, texts in lists:
        if path[0] == "letter_complexity":
            name = "letter/complexity_paper/" + "/".join(path[1:])
        else:
            name = "/".join(path)
        assert specs.suite(name) == texts


def test_data_file_agrees_with_the_reference_transcription():
    try:
        with open(REFERENCE) as f:
            reference = yaml.safe_load(f)
    except FileNotFoundError:
        pytest.skip("reference transcription not available on this machine")
    with resources.files("specrl_jax.specs").joinpath("data", "paper_specs.yaml").open() as f:
        assert yaml.safe_load(f) == reference


@pytest.mark.parametrize("name", [n for n in specs.list_suites() if "/complexity/" not in n])
def test_static_suite_parses_uses_world_props_and_is_satisfiable(name):
    info = specs.suite_info(name)
    assert info.formulas and info.horizon in ("finite", "infinite")
    assert info.env_family in ("letter", "zone", "arm", "multi_agent_zone")
    for text in info.formulas:
        specs.parse(text, info.propositions)
        assert specs.is_satisfiable(text, info.propositions, info.alphabet), text


def test_horizon_metadata_matches_the_formulas():
    for name in specs.list_suites():
        if "/complexity/" in name:
            continue
        info = specs.suite_info(name)
        guarantees = [spot.formula(t).is_syntactic_guarantee() for t in info.formulas]
        assert all(guarantees) == info.is_finite, name


def test_suite_metadata_examples():
    info = specs.suite_info("zone/finite/ood")
    assert info.propositions == ("blue", "green", "magenta", "yellow")
    assert info.env_family == "zone" and info.is_finite and len(info.formulas) == 5
    ma = specs.suite_info("multi_agent_zone/finite/coop")
    assert ma.alphabet == "per_agent_zero_or_one" and "green_1" in ma.propositions
    assert specs.suite_info("letter/infinite/rec").horizon == "infinite"
    assert specs.suite_info("arm_grippers_arm/finite/ind").env_family == "arm"
    assert len(specs.suite("genz/letter/finite")) == 8
    assert specs.list_suites("zone/") == [
        "zone/finite/ind",
        "zone/finite/ood",
        "zone/infinite/per",
        "zone/infinite/rec",
        "zone/infinite/rsp",
    ]


def test_unknown_suite_lists_close_matches_and_known_names():
    with pytest.raises(
        ValueError, match=r"Did you mean 'zone/finite/ood'.*Known suites:.*letter/finite/ind"
    ):
        specs.suite("zone/finite/odd")
    with pytest.raises(TypeError):
        specs.suite(3)


def test_complexity_grid_shapes_checked_by_spot():
    names = specs.list_suites("letter/complexity/")
    assert len(names) == 2 * 9 * 4
    for name in names:
        info = specs.suite_info(name)
        kind, cell = name.split("/")[2:]
        seq_len, num_disj = (int(x) for x in cell[3:].split("_disj"))
        assert len(info.formulas) == suites.COMPLEXITY_SIZE == len(set(info.formulas))
        assert info.is_finite and info.propositions == suites.LETTERS
        for text in info.formulas:
            if kind == "reach_only":
                goals = reach_only_chain(text)
                assert len(goals) == seq_len and all(len(g) == num_disj + 1 for g in goals)
            else:
                pairs = reach_avoid_chain(text)
                assert len(pairs) == seq_len
                assert all(len(r) == 1 and len(a) == num_disj + 1 for r, a in pairs)


def test_complexity_grid_is_satisfiable():
    for name in specs.list_suites("letter/complexity/"):
        for text in specs.suite(name):
            assert specs.is_satisfiable(text, suites.LETTERS), (name, text)


def test_complexity_grid_is_deterministic_and_seeded():
    cell = ("reach_avoid", 4, 1)
    assert suites.complexity_formulas(*cell) == suites.complexity_formulas(*cell)
    assert specs.suite("letter/complexity/reach_avoid/seq4_disj1") == list(
        suites.complexity_formulas(*cell)
    )
    assert suites.complexity_formulas(*cell, seed=1) != suites.complexity_formulas(*cell)
    assert suites.complexity_formulas("reach_only", 4, 1) != suites.complexity_formulas(*cell)


def test_grid_reach_avoid_rows_have_the_paper_shape():
    # every reach-avoid row of the paper's table is a cyclic chain, and a member of its cell's
    # 12 possible formulas (the grid draws 10 of them)
    for name in specs.list_suites("letter/complexity_paper/reach_avoid/"):
        seq_len, num_disj = (int(x) for x in name.rsplit("/", 1)[1][3:].split("_disj"))
        every = suites.complexity_formulas("reach_avoid", seq_len, num_disj, size=12)
        assert set(specs.suite(name)) <= set(every), name
        assert set(specs.suite(f"letter/complexity/reach_avoid/seq{seq_len}_disj{num_disj}")) < set(
            every
        )
    with pytest.raises(ValueError, match="at least 13 propositions"):
        specs.formulas.cyclic_reach_avoid(suites.LETTERS, 2, 11, 0)


def test_grid_reach_avoid_automata_stay_small():
    from specrl_jax.automata import translate, zero_or_one

    sizes = {}
    for seq_len in suites.COMPLEXITY_SEQ_LENS:
        for num_disj in suites.COMPLEXITY_DISJ:
            # the formulas of a cell differ by a renaming of letters: one stands for all
            text = suites.complexity_formulas("reach_avoid", seq_len, num_disj)[0]
            aut = translate.translate(text, suites.LETTERS, zero_or_one(len(suites.LETTERS)))
            sizes[seq_len, num_disj] = aut.num_states
    assert max(sizes.values()) == sizes[10, 0] == 193
