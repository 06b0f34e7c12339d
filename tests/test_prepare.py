"""Raw datapoint → prepared Datapoint (SPEC §3): states given as views, fused clouds or meshes enter the
reconstruction at the matching stage. Known lumps stand in for the before and after objects."""

import numpy as np
import pytest
import yaml
from scipy.spatial import cKDTree

from dpsi.capture import capture
from dpsi.datapoint import load_datapoint, load_datapoint_sets, save_datapoint
from dpsi.heightmap import CELLS, footprint_centre, height_map
from dpsi.motions import MOTIONS, plan, write_waypoints
from dpsi.pointclouds import read_mesh, write_mesh, write_points
from dpsi.effectors import CYLINDER
from dpsi.prepare import (after_targets, build_datapoint, fill_particles, fuse_state, load_targets, load_trajectory,
                          prepare_datapoint, reconstruct_state, save_targets, save_trajectory, surface_points,
                          trajectory_and_start)
from dpsi.rawdata import load_raw_dataset, write_datapoints_table, write_views
from dpsi.reconstruction.filling import fill, pcd_target, prt_target
from dpsi.reconstruction.meshing import mesh_volume
from dpsi.shapes import lump

CENTRE = (-0.52, 0.01)
WORKSPACE = ((-0.62, -0.09, -0.01), (-0.42, 0.11, 0.10))
DENSITY = 6e7
BEFORE = lump((0.03, 0.025), wall=0.012, top=0.03, centre=CENTRE)
PRESSED = lump((0.032, 0.026), wall=0.012, top=0.022, centre=CENTRE)  # smaller volume than BEFORE
SPREAD = lump((0.036, 0.03), wall=0.015, top=0.026, centre=CENTRE)  # larger volume than BEFORE
START = (*CENTRE, 0.03)


@pytest.fixture(scope="module")
def raw(tmp_path_factory):
    root = tmp_path_factory.mktemp("prepare") / "raw"
    root.mkdir()
    (root / "dataset.yaml").write_text(yaml.safe_dump(
        {"table_z": 0.0, "workspace": {"lo": list(WORKSPACE[0]), "hi": list(WORKSPACE[1])}}))
    write_datapoints_table(root / "datapoints.csv", [
        dict(id="views", motion="poking-1", effector="round", level=1, role="train", material="clay"),
        dict(id="meshes", motion="poking-2", effector="rectangle", level=1, role="validation", material="clay"),
        dict(id="mixed", motion="poking-1", effector="cylinder", level=1, role="train", material="clay")])
    (root / "trajectories").mkdir()
    for name in ("poking-1", "poking-2"):
        write_waypoints(root / "trajectories" / f"{name}.csv", plan(MOTIONS[name], seed=1, start_xyz=START))
    write_views(root / "views" / "before", capture(BEFORE, seed=1))
    write_views(root / "views" / "after", capture(PRESSED, seed=2))
    for folder in ("meshes", "mixed"):
        (root / folder).mkdir()
    write_mesh(root / "meshes" / "before_mesh.obj", BEFORE)
    write_mesh(root / "meshes" / "after_mesh.ply", SPREAD)
    write_mesh(root / "mixed" / "before_mesh.obj", BEFORE)
    write_points(root / "mixed" / "after_fused.npy", surface_points(PRESSED))
    return load_raw_dataset(root)


@pytest.fixture(scope="module")
def from_views(raw):
    return prepare_datapoint(raw, "views", DENSITY)


def test_views_become_a_datapoint(from_views, tmp_path):
    dp = from_views
    assert (dp.id, dp.motion, dp.effector.name) == ("views", "poking-1", "round")
    assert len(dp.particles) == pytest.approx(DENSITY * mesh_volume(BEFORE), rel=0.12)
    assert dp.particle_volume == pytest.approx(1 / DENSITY)
    assert 0 < len(dp.prt_target) <= len(dp.particles)
    assert len(dp.prt_target) == pytest.approx(DENSITY * mesh_volume(PRESSED), rel=0.15)
    assert 0.05 * len(dp.particles) < len(dp.pcd_target) < 0.4 * len(dp.particles)
    np.testing.assert_allclose(dp.centre_xy, CENTRE, atol=0.003)
    assert dp.heightmap.shape == (CELLS, CELLS)
    assert dp.heightmap.max() == pytest.approx(0.022, abs=0.002)  # the pressed top, not the before one
    assert dp.heightmap[0, 0] == 0.0  # empty cells hold the table height
    np.testing.assert_allclose(dp.start, START, atol=1e-12)
    assert dp.trajectory.n_steps == MOTIONS["poking-1"].sim_steps
    assert dp.table_z == 0.0
    save_datapoint(tmp_path / "views.npz", dp)
    again = load_datapoint(tmp_path / "views.npz")
    np.testing.assert_array_equal(again.particles, dp.particles)
    np.testing.assert_array_equal(again.heightmap, dp.heightmap)


def test_a_datapoint_named_in_two_sets_is_read_once_and_shared(from_views, tmp_path):
    for name in ("a", "b"):
        save_datapoint(tmp_path / f"{name}.npz", from_views)
    training, validation = load_datapoint_sets([tmp_path / "a.npz", tmp_path / "b.npz"], [tmp_path / "a.npz"])
    assert validation[0] is training[0] and training[1] is not training[0]
    np.testing.assert_array_equal(training[1].particles, from_views.particles)


@pytest.mark.parametrize("damage", [lambda b: b[: len(b) // 2], lambda b: b[:100] + bytes([b[100] ^ 0xFF]) + b[101:]])
def test_a_damaged_prepared_datapoint_names_the_file_and_the_stage_to_rerun(from_views, tmp_path, damage):
    save_datapoint(tmp_path / "views.npz", from_views)
    (tmp_path / "views.npz").write_bytes(damage((tmp_path / "views.npz").read_bytes()))
    with pytest.raises(ValueError, match=rf"^{tmp_path / 'views.npz'} is not a complete prepared datapoint file "
                                         r"\(.+\): it is damaged, cut short .*; delete it and rerun the stage that makes it \(prepare\)$"):
        load_datapoint(tmp_path / "views.npz")


def test_meshes_enter_at_filling_and_prt_target_fits(raw):
    dp = prepare_datapoint(raw, "meshes", DENSITY)
    before = read_mesh(raw.root / "meshes" / "before_mesh.obj")
    np.testing.assert_array_equal(dp.particles, fill(before, DENSITY))  # no fusion or meshing on the way
    after = read_mesh(raw.root / "meshes" / "after_mesh.ply")
    assert len(fill(after, DENSITY)) > len(dp.particles)  # the after mesh holds more at this density ...
    assert len(dp.prt_target) <= len(dp.particles)  # ... so the PRT target was thinned to fit
    np.testing.assert_array_equal(dp.prt_target, prt_target(after, DENSITY, len(dp.particles))[0])
    assert dp.heightmap.max() == pytest.approx(0.026, abs=0.0005)  # from points sampled on the mesh
    points = surface_points(after)
    np.testing.assert_array_equal(dp.heightmap, height_map(points, footprint_centre(dp.particles)))
    assert np.abs(np.asarray(after.get_min_bound()) - points.min(axis=0)).max() < 0.002


def test_stages_alone_match_the_composition(raw, from_views, tmp_path):
    views_dp, mixed = raw.datapoints[0], raw.datapoints[2]
    points, mesh = reconstruct_state(views_dp.before, raw.workspace, raw.table_z, "views before")
    fused = fuse_state(views_dp.before.load(), raw.workspace, raw.table_z)
    assert len(points) == pytest.approx(len(fused), rel=0.01)  # (threaded ICP may change the last digits)
    assert np.percentile(cKDTree(fused).query(points)[0], 99) < 1e-6
    assert len(fill_particles(mesh, DENSITY)) == pytest.approx(len(from_views.particles), rel=0.01)

    after_points, after_mesh = reconstruct_state(mixed.after, raw.workspace, raw.table_z, "mixed after")
    np.testing.assert_array_equal(after_points, mixed.after.load())  # a fused cloud is used as it is
    dp = build_datapoint(mixed, CYLINDER, BEFORE, after_mesh, after_points, DENSITY, raw.table_z)
    targets = after_targets(after_mesh, after_points, dp.particles, DENSITY, 0.0, mixed.after.measured)
    np.testing.assert_array_equal(dp.pcd_target, pcd_target(after_points))
    np.testing.assert_array_equal(dp.heightmap, targets.heightmap)
    trajectory, start = trajectory_and_start(mixed.trajectory)
    np.testing.assert_array_equal(dp.trajectory.positions, trajectory.positions)
    np.testing.assert_allclose(start, START, atol=1e-12)
    # the workflow's stage files give back exactly what was written
    save_targets(tmp_path / "targets.npz", targets)
    save_trajectory(tmp_path / "trajectory.npz", trajectory, start)
    read = load_targets(tmp_path / "targets.npz")
    np.testing.assert_array_equal(read.prt_target, targets.prt_target)
    np.testing.assert_array_equal(read.centre_xy, footprint_centre(dp.particles))
    read_trajectory, read_start = load_trajectory(tmp_path / "trajectory.npz")
    np.testing.assert_array_equal(read_trajectory.yaw, trajectory.yaw)
    np.testing.assert_array_equal(read_start, start)


def test_errors_name_the_datapoint(raw):
    with pytest.raises(ValueError, match="views before: fusing camera views needs a workspace"):
        fuse_state(raw.datapoints[0].before.load(), None, 0.0, "views before")
    with pytest.raises(ValueError, match="views before: fusion: view 0 shows no table"):
        fuse_state(raw.datapoints[0].before.load(), raw.workspace, 0.05, "views before")
    with pytest.raises(KeyError, match="'nowhere' is not in the raw dataset"):
        prepare_datapoint(raw, "nowhere", DENSITY)
    with pytest.raises(ValueError, match="tiny: no particles fit"):
        fill_particles(lump((0.001, 0.001), wall=0.0005, top=0.001, centre=CENTRE), DENSITY, "tiny")
