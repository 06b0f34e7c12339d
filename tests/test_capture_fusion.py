"""Synthetic capture → fusion → meshing → filling on a known object standing on the table (SPEC §3)."""

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial import cKDTree

from dpsi.capture import capture
from dpsi.reconstruction.filling import fill, lattice_spacing, particles_to_mesh, pcd_target, prt_target
from dpsi.heightmap import height_map, interior_cells
from dpsi.prepare import target_heightmap
from dpsi.reconstruction.fusion import fuse, smooth_surface
from dpsi.reconstruction.meshing import MeshingError, is_watertight, mesh_volume, reconstruct_mesh
from dpsi.shapes import lump

CENTRE = (-0.52, 0.01)
LO, HI = (-0.60, -0.07, -0.01), (-0.44, 0.09, 0.10)


def distance_to(mesh, points):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()


@pytest.fixture(scope="module")
def truth():
    mesh = lump((0.035, 0.035), wall=0.012, top=0.03, centre=CENTRE)
    assert is_watertight(mesh)
    return mesh


@pytest.fixture(scope="module")
def views(truth):
    return capture(truth, seed=3)


@pytest.fixture(scope="module")
def fused(views):
    return fuse(views, LO, HI)


@pytest.fixture(scope="module")
def mesh(fused):
    return reconstruct_mesh(fused, name="dome")


def test_capture_sees_no_bottom_and_is_deterministic(truth, views):
    assert len(views) == 6
    again = capture(truth, seed=3)
    np.testing.assert_array_equal(views[2].points, again[2].points)
    assert not np.array_equal(capture(truth, seed=4)[2].points, views[2].points)
    for view in views:
        assert (view.points[:, 2] > 0.1).all()  # camera frame: in front of the camera, ~0.3 m away
        base = view.in_base()
        near = distance_to(truth, base) < 0.006
        assert near.sum() > 500  # it sees the object ...
        assert (base[:, 2] > -0.01).all()  # ... and the table, never anything below it
    # the believed extrinsics are off: the table seen by different views lies at different heights
    table_heights = [np.median(v.in_base()[np.abs(v.in_base()[:, 2]) < 0.01, 2]) for v in views]
    assert np.ptp(table_heights) > 0.0005


def test_fused_cloud_is_close_to_the_true_surface(truth, views, fused):
    visible = fuse(views, LO, HI, close=False)
    surface = np.asarray(truth.sample_points_uniformly(20000).points)
    upper = surface[surface[:, 2] > 0.004]  # what the cameras can see
    to_truth = distance_to(truth, visible).mean()
    to_cloud = cKDTree(visible).query(upper)[0].mean()
    chamfer_mm = (to_truth + to_cloud) * 1e3
    assert chamfer_mm < 2.0
    # the closed cloud covers the bottom too
    assert cKDTree(fused).query(surface)[0].mean() * 1e3 < 1.5
    assert np.isclose(fused[:, 2].min(), 0.0, atol=1e-9)
    # without registration the calibration error shows (views ~±3 mm apart)
    unregistered = fuse(views, LO, HI, close=False, register=False)
    assert distance_to(truth, unregistered).mean() > to_truth


def test_the_target_height_map_is_not_raised_by_the_depth_noise(truth, fused):
    """A cell's height is its highest point, so the cameras' 0.5 mm depth noise in the fused cloud raises
    the map (0.33 mm on this dome, 0.7 mm on the twin's flattened lump); the target's height map, made from
    the smoothed cloud, must sit at the true surface's on average."""
    surface = np.asarray(truth.sample_points_uniformly(200000).points)
    true_map = height_map(surface, CENTRE)
    raw = height_map(fused, CENTRE)
    inside = interior_cells(true_map, raw, floor=0.0, erosion=2)
    assert inside.sum() > 150
    assert 0.25 < (raw - true_map)[inside].mean() * 1e3 < 1.2
    assert abs((target_heightmap(fused, CENTRE, 0.0, measured=True) - true_map)[inside].mean() * 1e3) < 0.15


def test_smoothing_projects_noise_away_and_keeps_a_plane():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.02, 0.02, (4000, 2))
    plane = np.column_stack([xy, 0.01 + 0.2 * xy[:, 0]])  # tilted: z follows x
    noisy = plane + rng.normal(0.0, 0.0005, plane.shape) * [0, 0, 1]
    smoothed = smooth_surface(noisy, 30)
    residual = smoothed[:, 2] - (0.01 + 0.2 * smoothed[:, 0])
    assert residual.std() < 0.0002 and abs(residual.mean()) < 2e-5
    np.testing.assert_allclose(smooth_surface(plane, 30), plane, atol=1e-12)
    with pytest.raises(ValueError, match="fewer than the 30 neighbours"):
        smooth_surface(noisy[:20], 30)


def test_mesh_is_watertight_with_the_right_volume(truth, mesh):
    assert is_watertight(mesh)
    assert mesh_volume(mesh) == pytest.approx(mesh_volume(truth), rel=0.10)
    assert np.percentile(distance_to(truth, np.asarray(mesh.vertices)), 95) < 0.003


@pytest.mark.parametrize("density", [4e7, 8e7])
def test_filling_count_matches_density_times_volume(mesh, density):
    particles = fill(mesh, density)
    assert len(particles) == pytest.approx(density * mesh_volume(mesh), rel=0.03)
    spacing = lattice_spacing(density)
    assert particles[:, 2].min() == pytest.approx(spacing / 2, abs=1e-9)
    d = cKDTree(particles).query(particles, k=2)[0][:, 1]
    np.testing.assert_allclose(d, spacing, rtol=1e-6)


def test_targets(mesh, fused):
    sim = fill(mesh, 6e7)
    target, density = prt_target(mesh, 6e7, max_particles=len(sim) - 200)
    assert len(target) <= len(sim) - 200 and density < 6e7
    assert len(fill(mesh, density / 0.95)) > len(sim) - 200  # stopped at the first density that fits
    pcd = pcd_target(fused)
    assert 0.05 * len(sim) < len(pcd) < 0.4 * len(sim)
    assert cKDTree(fused).query(pcd)[0].max() < 0.005


def test_particles_to_mesh_is_watertight_and_keeps_volume(truth):
    spacing = lattice_spacing(6e7)
    particles = fill(truth, 6e7)
    wrapped = particles_to_mesh(particles, spacing)
    assert is_watertight(wrapped)
    assert mesh_volume(wrapped) == pytest.approx(len(particles) * spacing**3, rel=0.08)
    assert mesh_volume(wrapped) == pytest.approx(mesh_volume(truth), rel=0.08)


def test_meshing_failure_names_the_input():
    line = np.column_stack([np.linspace(0, 0.05, 200), np.zeros(200), np.zeros(200)])
    with pytest.raises(MeshingError, match="datapoint-7"):
        reconstruct_mesh(line, name="datapoint-7")
