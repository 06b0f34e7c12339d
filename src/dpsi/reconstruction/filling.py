"""Particles inside a mesh, loss targets, and surface meshes of particle sets (SPEC §3.3–3.4).
Units: metres; densities in particles/m³.

Filling puts particles on a regular cubic lattice of spacing a = density^(-1/3), centred on the mesh's
bounding box in x and y and with its lowest layer a/2 above the mesh's lowest point (the table), so each
particle's cube of volume a³ rests on the table; it keeps the lattice points inside the mesh (ray-parity occupancy test, so the winding of the mesh does
not matter). Every particle stands for the same volume 1/density.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pymeshlab

from dpsi.files import check_points
from dpsi.reconstruction.fusion import voxel_downsample
from dpsi.reconstruction.meshing import MeshingError, is_watertight, repair

PCD_VOXEL = 0.005
"""Voxel (m) downsampling the fused after cloud into the PCD target."""

DENSITY_SHRINK = 0.95
"""Factor applied to the density until the PRT target has no more particles than the simulation."""


def lattice_spacing(density: float) -> float:
    """Lattice spacing (m) giving ``density`` particles/m³: density^(-1/3)."""
    if not np.isfinite(density) or density <= 0:
        raise ValueError(f"particle density must be a positive number of particles/m³, not {density}")
    return float(density) ** (-1.0 / 3.0)


def fill(mesh: o3d.geometry.TriangleMesh, density: float) -> np.ndarray:
    """Particles (n, 3) in m on a cubic lattice at ``density`` particles/m³ inside the closed ``mesh``."""
    if len(mesh.triangles) == 0:
        raise ValueError("fill: the mesh has no triangles")
    a = lattice_spacing(density)
    lo, hi = mesh.get_min_bound(), mesh.get_max_bound()
    centre = (lo + hi) / 2
    half = np.floor((hi - lo) / (2 * a)).astype(int) + 1
    axes = [centre[k] + a * np.arange(-half[k], half[k] + 1) for k in range(2)]
    axes.append(lo[2] + a * (np.arange(int(np.ceil((hi[2] - lo[2]) / a))) + 0.5))
    lattice = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    inside = scene.compute_occupancy(o3d.core.Tensor(lattice.astype(np.float32))).numpy() > 0.5
    return lattice[inside]


def prt_target(after_mesh: o3d.geometry.TriangleMesh, density: float, max_particles: int,
               shrink: float = DENSITY_SHRINK) -> tuple[np.ndarray, float]:
    """PRT target (SPEC §3.4): particles filled into ``after_mesh``, starting at ``density`` and
    multiplying it by ``shrink`` until there are at most ``max_particles`` (the simulated object's count).
    Returns the particles (n, 3) in m and the density used (particles/m³)."""
    if max_particles < 1:
        raise ValueError(f"max_particles must be at least 1, not {max_particles}")
    if not 0 < shrink < 1:
        raise ValueError(f"shrink factor must lie in (0, 1), not {shrink}")
    while True:
        particles = fill(after_mesh, density)
        if len(particles) == 0:
            raise ValueError(f"PRT target: the after mesh holds no particles at {density:.4g} particles/m³")
        if len(particles) <= max_particles:
            return particles, density
        density *= shrink


def pcd_target(fused_after, voxel: float = PCD_VOXEL) -> np.ndarray:
    """PCD target (SPEC §3.4): the fused after cloud (n, 3) in m voxel-downsampled at ``voxel`` m."""
    return voxel_downsample(check_points(fused_after, "fused after cloud"), voxel)


_TETRAHEDRON = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) * (0.05 / np.sqrt(3))
_TETRAHEDRON_FACES = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])


def particles_to_mesh(particles, spacing: float, name: str = "particles") -> o3d.geometry.TriangleMesh:
    """Watertight, outward-wound surface mesh (m) of a particle set (n, 3) with lattice ``spacing`` (m).

    Uses an alpha wrap (CGAL via PyMeshLab) with ball size 2·spacing, offset spacing/2 outside the
    particle centres, so the enclosed volume is close to n·spacing³; gaps narrower than about
    2·spacing are bridged. (The wrap needs triangles, so each particle enters as a tetrahedron a tenth
    of the spacing across.) Raises :class:`MeshingError` naming ``name`` if the result is not watertight."""
    particles = check_points(particles, name)
    if not spacing > 0:
        raise ValueError(f"{name}: particle spacing must be positive, not {spacing} m")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh((particles[:, None, :] + _TETRAHEDRON * spacing).reshape(-1, 3),
                               (4 * np.arange(len(particles))[:, None, None] + _TETRAHEDRON_FACES).reshape(-1, 3)))
    ms.generate_alpha_wrap(alpha=pymeshlab.PureValue(2 * spacing), offset=pymeshlab.PureValue(spacing / 2))
    mesh = repair(o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(ms.current_mesh().vertex_matrix()),
                                            o3d.utility.Vector3iVector(ms.current_mesh().face_matrix())))
    if not is_watertight(mesh):
        raise MeshingError(f"{name}: the alpha wrap of {len(particles)} particles is not watertight")
    return mesh


__all__ = ["PCD_VOXEL", "DENSITY_SHRINK", "lattice_spacing", "fill", "prt_target", "pcd_target",
           "particles_to_mesh"]
