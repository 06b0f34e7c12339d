"""SPEC §6 dataset selection over a datapoints table (the default twin's table, no simulation)."""

import pandas as pd
import pytest

from dpsi.datasets import DATASETS, EFFECTORS, LONG_MOTIONS, expand_names, ood, planning_start, select, unseen, validation
from dpsi.motions import MOTIONS
from dpsi.twin_plan import default_plan, plan_rows


@pytest.fixture(scope="module")
def table():
    return pd.DataFrame(plan_rows(default_plan(train=3)))


def rows(table, ids):
    return table.set_index("id").loc[ids]


@pytest.mark.parametrize("level, a, b", [(1, "poking-1", "poking-2"), (2, "poking-shifting-1", "poking-shifting-2")])
def test_mixes_take_the_first_train_datapoints_of_each_combination(table, level, a, b):
    mix12 = rows(table, select(table, level, "12-mix"))
    assert len(mix12) == 12 and set(mix12.role) == {"train"} and set(mix12.material) == {"clay"}
    assert (mix12.level.astype(int) == level).all()
    assert mix12.groupby(["motion", "effector"]).size().to_dict() == {(m, e): 2 for m in (a, b) for e in EFFECTORS}
    assert all(i.endswith(("-0", "-1")) for i in mix12.index)  # the first two of three
    mix6 = select(table, level, "6-mix")
    assert len(mix6) == 6 and set(mix6) < set(mix12.index) and all(i.endswith("-0") for i in mix6)
    for effector in EFFECTORS:
        (one,) = select(table, level, f"1-{effector}")
        assert tuple(rows(table, [one]).iloc[0][["motion", "effector"]]) == (b, effector)
        assert one in mix6


def test_first_means_first_in_table_order(table):
    reversed_table = table.iloc[::-1]
    assert select(reversed_table, 1, "1-round") == ["clay-poking-2-round-train-2"]
    assert select(reversed_table, 1, "12-mix")[:2] == ["clay-poking-1-rectangle-train-2",
                                                       "clay-poking-1-rectangle-train-1"]


def test_materials_are_kept_apart(table):
    assert select(table, 2, "1-cylinder", material="slime") == ["slime-poking-shifting-2-cylinder-train-0"]
    assert select(table, 2, "1-cylinder") == ["clay-poking-shifting-2-cylinder-train-0"]
    assert validation(table, 2, material="soil") == ["soil-flattening-cylinder-validation-0"]


def test_validation_and_ood_sets(table):
    for level, b in ((1, "poking-2"), (2, "poking-shifting-2")):
        val = rows(table, validation(table, level))
        assert len(val) == 6 and set(val.motion) == {b} and set(val.role) == {"validation"}
        assert val.effector.value_counts().to_dict() == {e: 2 for e in EFFECTORS}
    out = rows(table, ood(table))
    assert len(out) == 6 and set(out.material) == {"clay"}
    assert {(m, e) for m, e in zip(out.motion, out.effector)} == {(m, MOTIONS[m].effector) for m in LONG_MOTIONS}


def test_every_dataset_of_the_default_twin_is_complete():
    table = pd.DataFrame(plan_rows(default_plan()))
    assert len(table) == 2 * (12 + 6) + 6 + 2 * 2
    for level in (1, 2):
        for name in DATASETS:
            assert len(select(table, level, name)) == {"12-mix": 12, "6-mix": 6}.get(name, 1)


def test_unknown_dataset_lists_the_known_ones(table):
    with pytest.raises(ValueError, match=r"unknown dataset '3-mix'.*12-mix.*1-cylinder"):
        select(table, 1, "3-mix")
    with pytest.raises(ValueError, match="level must be 1 or 2"):
        select(table, 3, "6-mix")


def test_missing_datapoints_are_named(table):
    short = table[~table.id.isin(["clay-poking-1-round-train-1", "clay-poking-1-round-train-2"])]
    short = short[~short.id.str.startswith("clay-poking-2-cylinder-train")]
    with pytest.raises(ValueError, match=r"2 of poking-1 with round \(found 1\); 2 of poking-2 with cylinder \(found 0\)"):
        select(short, 1, "12-mix")
    with pytest.raises(ValueError, match=r"1 of poking-2 with cylinder \(found 0\)"):
        select(short, 1, "6-mix")
    with pytest.raises(ValueError, match="no validation or train datapoints of level 1 for material 'slime'"):
        validation(table, 1, material="slime")
    with pytest.raises(ValueError, match="no ood datapoints"):
        ood(table[table.role != "ood"])
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['material'\]"):
        select(table.drop(columns="material"), 1, "6-mix")


def test_planning_starts_from_the_first_ood_flattening_of_clay():
    table = pd.DataFrame({"id": ["a", "b", "c", "d"], "material": ["clay", "clay", "slime", "clay"],
                          "level": ["2"] * 4, "role": ["train", "ood", "ood", "ood"],
                          "motion": ["poking-2", "triple-poking", "flattening", "flattening"],
                          "effector": ["round", "round", "cylinder", "cylinder"]})
    table = table.assign(**{c: "x" for c in ("before", "after", "trajectory") if c not in table})
    assert planning_start(table) == "d"
    with pytest.raises(ValueError, match="flattening"):
        planning_start(table[table.id != "d"])


@pytest.fixture
def real():
    """A table like the published real data's: pairs of any motions, all train datapoints."""
    return pd.DataFrame([dict(id=i, motion=m, effector=e, level=lv, role="train", material="clay") for i, m, e, lv in [
        ("a", "poking-1", "round", 1), ("b", "poking-1", "cylinder", 1), ("c", "poking-2", "rectangle", 1),
        ("d", "poking-shifting-1", "cylinder", 2), ("e", "poking-shifting-2", "round", 2)]])


def test_pairs_stand_for_one_dataset_per_train_datapoint_and_mix_for_all(real):
    assert expand_names(real, 1, ["pairs", "mix"]) == ["pair-a", "pair-b", "pair-c", "mix"]
    assert expand_names(real, 2, ["1-round", "pairs"]) == ["1-round", "pair-d", "pair-e"]
    assert select(real, 1, "pair-b") == ["b"] and select(real, 2, "mix") == ["d", "e"]
    with pytest.raises(ValueError, match="no train datapoint 'd'"):
        select(real, 1, "pair-d")


def test_without_validation_datapoints_a_dataset_validates_on_the_pairs_it_leaves_out(real, table):
    assert validation(real, 1, training=["b"]) == ["a", "c"]
    assert validation(real, 1, training=["a", "b", "c"]) == ["a", "b", "c"]  # nothing left out: itself
    assert validation(table, 1, training=select(table, 1, "1-round")) == validation(table, 1)  # the twin's own


def test_unseen_datapoints_span_both_levels(real):
    assert unseen(real, ["b"]) == ["a", "c", "d", "e"]
    assert unseen(real, ["d", "e"]) == ["a", "b", "c"]
