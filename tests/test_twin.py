"""The synthetic twin: a tiny twin (one poking-2 datapoint, a coarse simulator, few particles) makes a valid
raw dataset whose after state is pressed in where the effector went down; generation is deterministic."""

import json

import numpy as np
import pytest

from dpsi.datasets import select
from dpsi.heightmap import CELLS, SIZE, height_map
from dpsi.motions import read_waypoints
from dpsi.pointclouds import read_points
from dpsi.prepare import fuse_state
from dpsi.rawdata import load_raw_dataset
from dpsi.reconstruction.filling import lattice_spacing
from dpsi.simulation import SimulatorConfig
from dpsi.twin import (GROUND_TRUTH_FILE, WORKSPACE, MotionError, generate_datapoint, generate_twin, load_ground_truth,
                       read_truth, write_twin_table)
from dpsi.twin_plan import MATERIALS, Group, default_plan, plan_from_config, plan_rows

TINY = dict(config=SimulatorConfig(dx=0.008, max_particles=2000, max_steps=100), density=8e6)
PLAN = (Group("clay", 1, "train", ("poking-2",), ("round",), 1),)
ID = "clay-poking-2-round-train-0"


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    root = tmp_path_factory.mktemp("twin") / "raw" / "tiny"
    generate_twin(root, PLAN, seed=3, **TINY)
    return root


def view_heights(ds, state, centre_xy):
    """Height map (m) of the fused views of a state."""
    return height_map(fuse_state(state.load(), ds.workspace, ds.table_z), centre_xy)


def test_twin_is_a_valid_raw_dataset(twin):
    ds = load_raw_dataset(twin)
    (dp,) = ds.datapoints
    assert (dp.id, dp.motion, dp.effector, dp.level, dp.role, dp.material) == (ID, "poking-2", "round", 1, "train", "clay")
    assert dp.before.form == dp.after.form == "views"
    assert len(dp.before.paths) == len(dp.after.paths) == 6
    assert dp.trajectory == twin / ID / "trajectory.csv"
    assert ds.table_z == 0.0 and np.allclose(ds.workspace, WORKSPACE)
    assert select(ds, 1, "1-round") == [ID]
    materials, seed, config, density, motion_error = read_truth(twin)
    assert materials == {"clay": MATERIALS["clay"]} and seed == 3
    assert config == TINY["config"] and density == TINY["density"] and motion_error == MotionError()
    assert json.loads((twin / "truth.json").read_text())["materials"]["clay"]["E"] == MATERIALS["clay"].E


def test_trajectory_starts_at_the_top_centre(twin):
    truth = load_ground_truth(twin / ID / GROUND_TRUTH_FILE)
    waypoints = read_waypoints(twin / ID / "trajectory.csv")
    start = waypoints.xyz[0]
    np.testing.assert_allclose(start[:2], truth.centre_xy, atol=0.001)
    spacing = lattice_spacing(TINY["density"])
    assert truth.before_particles[:, 2].max() < start[2] < truth.before_particles[:, 2].max() + spacing
    assert len(waypoints.t) == 40 and np.isclose(waypoints.t[-1], 0.93)


def test_after_state_is_pressed_where_the_effector_went_down(twin):
    ds = load_raw_dataset(twin)
    (dp,) = ds.datapoints
    start = read_waypoints(dp.trajectory).xyz[0]
    before, after = view_heights(ds, dp.before, start[:2]), view_heights(ds, dp.after, start[:2])
    g = (np.arange(CELLS) + 0.5) * SIZE / CELLS - SIZE / 2
    r = np.hypot(*np.meshgrid(g, g, indexing="ij"))
    drop_mm = (before - after) * 1e3
    assert 5.0 < drop_mm[r < 0.006].mean() < 20.0  # a 20 mm poke leaves a dent of several mm
    ring = (r > 0.02) & (r < 0.028) & (before > 0.005)
    assert np.median(np.abs(drop_mm[ring])) < 3.0  # away from the effector the top hardly moves
    truth = load_ground_truth(twin / ID / GROUND_TRUTH_FILE)
    assert truth.before_particles.shape == truth.after_particles.shape
    assert truth.parameters == MATERIALS["clay"] and truth.particle_volume == pytest.approx(1 / TINY["density"])
    assert truth.heightmap.shape == (CELLS, CELLS)
    assert truth.heightmap.max() < truth.before_particles[:, 2].max() + 0.004


def test_generation_is_deterministic_from_the_seed(twin, tmp_path):
    write_twin_table(tmp_path / "same", PLAN, seed=3, **TINY)
    write_twin_table(tmp_path / "other", PLAN, seed=4, **TINY)
    same, other = generate_datapoint(tmp_path / "same", ID), generate_datapoint(tmp_path / "other", ID)
    for state in ("before", "after"):
        for k in (0, 5):
            a = read_points(twin / ID / state / f"view_{k}.ply")
            np.testing.assert_array_equal(read_points(same / state / f"view_{k}.ply"), a)
            assert (twin / ID / state / f"view_{k}.transform.txt").read_text() == \
                (same / state / f"view_{k}.transform.txt").read_text()
            assert read_points(other / state / f"view_{k}.ply").shape != a.shape
    assert (same / "trajectory.csv").read_text() == (twin / ID / "trajectory.csv").read_text()
    t0, t1 = (load_ground_truth(p / GROUND_TRUTH_FILE) for p in (twin / ID, same))
    np.testing.assert_array_equal(t0.after_particles, t1.after_particles)
    assert not list(tmp_path.glob("*/.*.tmp"))  # no temporary folder left behind


def test_a_motion_error_moves_the_simulated_path_and_not_the_recorded_one(twin, tmp_path):
    """With a motion error the twin simulates its tool 3 mm off (at most) and turned a little, while its
    trajectory.csv keeps the planned path."""
    root = tmp_path / "raw" / "off"
    write_twin_table(root, PLAN, seed=3, **TINY, motion_error=MotionError(translation=0.003, yaw=0.05))
    generate_datapoint(root, ID)
    exact, off = load_ground_truth(twin / ID / GROUND_TRUTH_FILE), load_ground_truth(root / ID / GROUND_TRUTH_FILE)
    assert (root / ID / "trajectory.csv").read_bytes() == (twin / ID / "trajectory.csv").read_bytes()
    assert exact.motion_offset == (0.0, 0.0, 0.0) and exact.motion_yaw == 0.0
    moved = np.asarray(off.motion_offset)
    assert 0 < np.abs(moved).max() <= 0.003 and 0 < abs(off.motion_yaw) <= 0.05
    assert np.array_equal(off.before_particles, exact.before_particles)
    assert not np.allclose(off.after_particles, exact.after_particles, atol=1e-3)


def test_plans_and_their_errors(tmp_path):
    rows = plan_rows(default_plan())
    assert sum(r["material"] == "clay" and r["role"] == "ood" for r in rows) == 6
    assert {r["id"] for r in rows if r["material"] == "slime"} == {
        "slime-poking-shifting-2-cylinder-train-0", "slime-flattening-cylinder-validation-0"}
    assert plan_from_config([dict(material="clay", level=1, role="train", motions=["poking-2"],
                                  effectors=["round"], count=1)]) == PLAN
    with pytest.raises(ValueError, match="duplicate datapoint id"):
        plan_rows(PLAN + PLAN)
    with pytest.raises(ValueError, match="poking-1 belongs to level 1, not 2"):
        Group("clay", 2, "train", ("poking-1",), ("round",))
    with pytest.raises(ValueError, match="unknown effector 'spoon'"):
        Group("clay", 1, "train", ("poking-1",), ("spoon",))
    with pytest.raises(ValueError, match="fields are material"):
        plan_from_config([dict(material="clay", level=1, role="train", motion="poking-1")])
    with pytest.raises(ValueError, match=r"no ground-truth parameters for material\(s\) \['mud'\]"):
        write_twin_table(tmp_path, (Group("mud", 1, "train", ("poking-1",), ("round",)),))
    write_twin_table(tmp_path, PLAN, **TINY)
    with pytest.raises(KeyError, match="'nothing' is not in"):
        generate_datapoint(tmp_path, "nothing")
