"""The reconstruction chain on the published real clay meshes (robot frame), captured synthetically.

Each original mesh is captured as the cameras would (six partial, noisy views with calibration error),
then fused, meshed and filled; the results are compared with the original. The published meshes have
internal folds (vertical rays cross them up to 8 times), so their signed volume is not a reliable
enclosed volume; the reference volume is the one under their visible top surface, which is what a
camera from above plus the walls-at-≥90° assumption can recover.
"""


import numpy as np
import open3d as o3d
import pytest

from conftest import SHARED, shared
from dpsi.capture import capture
from dpsi.heightmap import height_map
from dpsi.pointclouds import read_mesh
from dpsi.reconstruction.filling import fill
from dpsi.reconstruction.fusion import fuse
from dpsi.reconstruction.meshing import is_watertight, mesh_volume, reconstruct_mesh

REAL_CLAY = SHARED / "real-clay"
PAIRS = {  # robot-frame (before, after) pairs, see real-clay/README.md
    "rectangle-8": ("data-motion-1/eef-rectangle/mesh_80.obj", "data-motion-1/eef-rectangle/mesh_81.obj"),
    "cylinder-5": ("data-motion-poking-1/eef-cylinder/mesh_50.obj", "data-motion-poking-1/eef-cylinder/mesh_51.obj"),
}

@pytest.fixture(autouse=True)
def real_clay():
    """Skip (saying why) without ../shared, fail under CI."""
    return shared("real-clay")


def top_surface(mesh, cell=0.001):
    """Points (n, 3) of the highest surface above a grid of ``cell`` (m), and the volume (m³) under it."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    lo, hi = mesh.get_min_bound(), mesh.get_max_bound()
    x, y = np.meshgrid(np.arange(lo[0], hi[0], cell) + cell / 2, np.arange(lo[1], hi[1], cell) + cell / 2)
    start = hi[2] + 0.05
    rays = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, start), np.zeros((x.size, 2)),
                            -np.ones(x.size)]).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    hit = np.isfinite(t)
    z = start - t[hit]
    return np.column_stack([x.ravel()[hit], y.ravel()[hit], z]), float((z - lo[2]).sum() * cell**2)


def reconstruct(mesh, seed):
    centre = mesh.get_axis_aligned_bounding_box().get_center()
    lo, hi = centre - [0.08, 0.08, 0.0], centre + [0.08, 0.08, 0.1]
    lo[2] = -0.01
    fused = fuse(capture(mesh, table_z=0.0, seed=seed), lo, hi)
    return fused, reconstruct_mesh(fused, name=f"synthetic capture of {mesh}")


@pytest.mark.parametrize("pair", PAIRS)
def test_real_clay_pair(pair):
    meshes = [read_mesh(REAL_CLAY / f) for f in PAIRS[pair]]
    centre = meshes[0].get_axis_aligned_bounding_box().get_center()[:2]
    maps = []
    for seed, original in enumerate(meshes):
        top, volume = top_surface(original)
        fused, mesh = reconstruct(original, seed)
        assert is_watertight(mesh)
        assert mesh_volume(mesh) == pytest.approx(volume, rel=0.15)  # measured 0.91-1.12 over 40 captures
        assert len(fill(mesh, 6e7)) == pytest.approx(6e7 * mesh_volume(mesh), rel=0.03)
        hm_true, hm_fused = height_map(top, centre), height_map(fused, centre)
        d_mm = np.abs(hm_true - hm_fused).sum() * 1e3
        assert d_mm < 800  # typical distances between datapoints are 2000-5000 mm
        maps.append((hm_true, hm_fused))
    # the reconstruction error is smaller than the change the motion made
    before_after = np.abs(maps[0][0] - maps[1][0]).sum() * 1e3
    assert max(np.abs(t - f).sum() * 1e3 for t, f in maps) < 0.8 * before_after
