"""Import of the published real clay data (dpsi.release_plan, dpsi.release) from the release's own layout,
built here from ../shared/real-clay's MANIFEST.csv, and from that folder itself."""

import json

import numpy as np
import pandas as pd
import pytest

from conftest import shared
from dpsi.motions import read_waypoints
from dpsi.pointclouds import read_mesh
from dpsi.rawdata import load_raw_dataset
from dpsi.release import import_release
from dpsi.release_plan import ImportTables, ReleaseError, find_pairs, plan_rows

TABLES = ImportTables(
    motions={"data-motion-1": ("poking-1", 1), "data-motion-poking-1": ("poking-1", 1),
             "data-motion-poking-shifting-1": ("poking-shifting-1", 2),
             "data-motion-poking-shifting-2": ("poking-shifting-2", 2)},
    effectors={"eef-rectangle": "rectangle", "eef-round": "round", "eef-cylinder": "cylinder"},
    roles={"poking-1-round-extra2": "validation"})


@pytest.fixture(scope="module")
def release(tmp_path_factory):
    """A clone of the data release as a user has it: data/<motion>/<effector>/[extra_data/]mesh_*_repaired*.obj,
    one link per file of MANIFEST.csv."""
    real = shared("real-clay")
    root = tmp_path_factory.mktemp("SI4RP-data")
    for row in pd.read_csv(real / "MANIFEST.csv", dtype=str).itertuples():
        (root / row.source_path).parent.mkdir(parents=True, exist_ok=True)
        (root / row.source_path).symlink_to(real / row.local_path)
    return root


def test_the_release_layout_and_the_manifest_give_the_same_pairs(release):
    from_release = [(p.motion_folder, p.effector_folder, p.subset, p.index, p.normalised) for p in find_pairs(release)]
    from_manifest = [(p.motion_folder, p.effector_folder, p.subset, p.index, p.normalised)
                     for p in find_pairs(shared("real-clay"))]
    assert from_release == from_manifest
    assert ("data-motion-poking-1", "eef-round", "extra_data", 2, True) in from_release
    assert len(from_release) == 5


def test_folders_become_motions_levels_effectors_and_roles(release):
    rows = {row["id"]: row for row, _ in plan_rows(release / "data", TABLES)}
    assert rows["1-rectangle-8"] == {"id": "1-rectangle-8", "motion": "poking-1", "effector": "rectangle", "level": 1,
                                     "role": "train", "material": "clay"}
    assert rows["poking-shifting-2-round-extra0"]["level"] == 2
    assert rows["poking-shifting-1-cylinder-1"]["motion"] == "poking-shifting-1"
    assert rows["poking-1-round-extra2"]["role"] == "validation"
    only_level_1 = ImportTables({"data-motion-1": ("poking-1", 1)}, TABLES.effectors, {})
    assert [row["id"] for row, _ in plan_rows(release, only_level_1)] == ["1-rectangle-8"]


def test_the_import_writes_a_raw_dataset_with_normalised_pairs_aligned(release, tmp_path):
    records = import_release(release, tmp_path / "real", TABLES)
    dataset = load_raw_dataset(tmp_path / "real")
    assert [d.id for d in dataset.datapoints] == [r["id"] for r in records]
    round_pair = {r["id"]: r for r in records}["poking-1-round-extra2"]
    assert round_pair["normalised"] and round_pair["repairs"]["before"]  # the published file needed mending
    before = read_mesh(tmp_path / "real" / "poking-1-round-extra2" / "before_mesh.obj")
    after = read_mesh(tmp_path / "real" / "poking-1-round-extra2" / "after_mesh.obj")
    assert before.get_min_bound()[2] == pytest.approx(0.0, abs=1e-9)
    assert after.get_min_bound()[2] == pytest.approx(0.0, abs=1e-9)
    footprint = lambda m: (m.get_min_bound()[:2] + m.get_max_bound()[:2]) / 2  # noqa: E731
    assert footprint(after) == pytest.approx(footprint(before), abs=1e-9)
    # a robot-frame pair keeps its frame, and its planned path starts at the top centre of its before mesh
    rectangle = read_mesh(tmp_path / "real" / "1-rectangle-8" / "before_mesh.obj")
    published = read_mesh(shared("real-clay/data-motion-1/eef-rectangle/mesh_80.obj"))
    assert np.allclose(rectangle.get_max_bound(), published.get_max_bound(), atol=1e-6)
    start = read_waypoints(tmp_path / "real" / "1-rectangle-8" / "trajectory.csv").xyz[0]
    assert start == pytest.approx([*footprint(published), published.get_max_bound()[2]], abs=1e-6)


def test_an_import_never_writes_over_a_dataset(release, tmp_path):
    import_release(release, tmp_path / "real", ImportTables({"data-motion-1": ("poking-1", 1)}, TABLES.effectors, {}))
    with pytest.raises(ReleaseError, match="already holds a raw dataset"):
        import_release(release, tmp_path / "real", TABLES)


@pytest.mark.parametrize("tables, message", [
    (ImportTables(TABLES.motions, TABLES.effectors, {"poking-9-round-1": "validation"}), "poking-9-round-1"),
    (ImportTables({"data-motion-9": ("poking-1", 1)}, TABLES.effectors, {}), "none of its pairs"),
])
def test_tables_that_name_nothing_in_the_release_are_refused(release, tables, message):
    with pytest.raises(ReleaseError, match=message):
        plan_rows(release, tables)


def test_a_folder_without_pairs_is_refused(tmp_path):
    with pytest.raises(ReleaseError, match="no mesh pairs"):
        find_pairs(tmp_path)
    with pytest.raises(ReleaseError, match="does not exist"):
        find_pairs(tmp_path / "missing")


def test_the_command_imports_with_the_tables_of_a_config(tmp_path, capsys):
    from conftest import ROOT
    from dpsi.__main__ import main
    assert main(["import-release", str(shared("real-clay")), str(tmp_path / "real"),
                 "--config", str(ROOT / "config" / "real.yaml")]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["id"] for r in records] == [d.id for d in load_raw_dataset(tmp_path / "real").datapoints]
    assert {r["motion"] for r in records} == {"poking-1", "poking-shifting-1", "poking-shifting-2"}


def test_the_command_names_a_config_without_a_release_section(tmp_path, capsys):
    from dpsi.__main__ import main
    (tmp_path / "c.yaml").write_text("dataset: x\n")
    with pytest.raises(SystemExit):
        main(["import-release", str(tmp_path), str(tmp_path / "real"), "--config", str(tmp_path / "c.yaml")])
    assert "c.yaml has no `release` section" in capsys.readouterr().err
