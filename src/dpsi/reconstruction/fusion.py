"""Fusion of camera views into one closed object cloud (SPEC §3.1). Units: metres, robot base frame.

Steps: transform each view to the base frame, crop it to the workspace box, fit the table plane near the
known table height and level the view on it (this removes the tilt and height part of the view's
calibration error), drop the table, register each view's object points to the other views (ICP, for the
remaining part of the calibration error), merge the views, voxel-downsample, remove outliers and stray
clusters, then close the bottom: the camera never sees it, so assuming walls meet the table at ≥ 90°,
the footprint's boundary points are extended straight down to the table and the footprint is covered
with table-height points.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import open3d as o3d
from scipy import ndimage
from scipy.spatial import cKDTree

from dpsi.files import check_points
from dpsi.pointclouds import View

TABLE_SEARCH = 0.008
"""Half-height (m) of the band around the known table height searched for the table plane."""

TABLE_FIT_TOL = 0.0015
"""Distance (m) from the fitted table plane within which a point counts as table when fitting."""


ICP_DECIMALS = 10
"""Decimals the ICP transform is rounded to (1e-10 m, 1e-10 rad): Open3D's multi-threaded ICP differs
from run to run in the last bits, which would make fusion — and a marginal meshing — irreproducible."""


def crop(points: np.ndarray, lo, hi) -> np.ndarray:
    """The points inside the axis-aligned box [lo, hi] (m)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    if lo.shape != (3,) or hi.shape != (3,) or not (lo < hi).all():
        raise ValueError(f"workspace box must be two (3,) corners with lo < hi, got lo={lo}, hi={hi}")
    return points[np.all((points >= lo) & (points <= hi), axis=1)]


def fit_table(points: np.ndarray, table_z: float) -> np.ndarray | None:
    """Plane (a, b, c) with z = a x + b y + c fitted to the table points of one view: points within
    :data:`TABLE_SEARCH` of ``table_z``, trimmed to those within :data:`TABLE_FIT_TOL` of the plane.
    ``None`` if fewer than 50 table points are found."""
    band = points[np.abs(points[:, 2] - table_z) < TABLE_SEARCH]
    if len(band) < 50:
        return None
    plane = np.array([0.0, 0.0, np.median(band[:, 2])])
    A = np.column_stack([band[:, :2], np.ones(len(band))])
    for _ in range(5):
        inliers = np.abs(A @ plane - band[:, 2]) < TABLE_FIT_TOL
        if inliers.sum() < 50:
            return None
        plane = np.linalg.lstsq(A[inliers], band[inliers, 2], rcond=None)[0]
    return plane


def level_on_table(points: np.ndarray, plane: np.ndarray, table_z: float) -> np.ndarray:
    """Rigidly move ``points`` so that the fitted ``plane`` (z = a x + b y + c) becomes z = ``table_z``:
    a rotation taking the plane normal to +z about the plane point below the points' centroid, then a
    vertical shift."""
    a, b, c = plane
    n = np.array([-a, -b, 1.0]) / np.linalg.norm([-a, -b, 1.0])
    axis = np.cross(n, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    R = np.eye(3) if s < 1e-12 else o3d.geometry.get_rotation_matrix_from_axis_angle(axis / s * np.arcsin(s))
    centre = points.mean(axis=0)
    pivot = np.array([centre[0], centre[1], a * centre[0] + b * centre[1] + c])
    out = (points - pivot) @ R.T + pivot
    out[:, 2] += table_z - pivot[2]
    return out


def remove_table(points: np.ndarray, table_z: float, margin: float) -> np.ndarray:
    """The points more than ``margin`` (m) above the table plane z = ``table_z``."""
    return points[points[:, 2] > table_z + margin]


def register_views(clouds: list[np.ndarray], max_distance: float = 0.006, normal_radius: float = 0.004,
                   rounds: int = 2) -> list[np.ndarray]:
    """The object clouds of the views (each (n, 3), m) moved rigidly onto each other: each view in turn is
    aligned by point-to-plane ICP (correspondences up to ``max_distance`` m) to the union of the others,
    for ``rounds`` passes."""
    reg = o3d.pipelines.registration
    clouds = list(clouds)
    for _ in range(rounds):
        for k in range(len(clouds)):
            target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
                np.vstack([c for j, c in enumerate(clouds) if j != k])))
            target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=30))
            source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(clouds[k]))
            T = reg.registration_icp(source, target, max_distance, np.eye(4),
                                     reg.TransformationEstimationPointToPlane()).transformation
            T = np.round(T, ICP_DECIMALS)
            clouds[k] = clouds[k] @ T[:3, :3].T + T[:3, 3]
    return clouds


SMOOTHING_NEIGHBOURS = 30
"""Points (itself included) whose least-squares plane :func:`smooth_surface` projects each point onto. The
cameras' depth noise (σ = 0.5 mm) raised the height map of a fused flat top by 0.7 mm, since a cell keeps
its highest point; smoothed with 30 neighbours, by 0.06 mm (docs/identifiability.md)."""


def smooth_surface(points: np.ndarray, neighbours: int = SMOOTHING_NEIGHBOURS) -> np.ndarray:
    """``points`` (n, 3) in m, each moved along the normal of the least-squares plane through its
    ``neighbours`` nearest points onto that plane: noise across the surface shrinks about √neighbours-fold,
    a smooth surface stays where it is (edges round off over the neighbourhood's width)."""
    if neighbours < 3:
        raise ValueError(f"smoothing needs at least 3 neighbours for a plane, got {neighbours}")
    if len(points) < neighbours:
        raise ValueError(f"smoothing: only {len(points)} points, fewer than the {neighbours} neighbours asked for")
    near = points[cKDTree(points).query(points, neighbours)[1]]
    centre = near.mean(axis=1)
    spread = near - centre[:, None]
    normal = np.linalg.eigh(np.einsum("nki,nkj->nij", spread, spread))[1][:, :, 0]
    return points - np.einsum("ni,ni->n", points - centre, normal)[:, None] * normal


def largest_cluster(points: np.ndarray, eps: float, min_points: int = 5) -> np.ndarray:
    """The points of the largest DBSCAN cluster (neighbour distance ``eps`` in m)."""
    labels = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
                        .cluster_dbscan(eps=eps, min_points=min_points))
    if (labels < 0).all():
        raise ValueError("fusion: no cluster found in the fused cloud (too few points?)")
    return points[labels == np.bincount(labels[labels >= 0]).argmax()]


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel of side ``voxel`` (m)."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    return np.asarray(cloud.voxel_down_sample(voxel).points)


def close_bottom(points: np.ndarray, table_z: float, spacing: float) -> np.ndarray:
    """``points`` plus wall points dropped from the footprint boundary down to the table and a grid of
    points covering the footprint at z = ``table_z``, all about ``spacing`` (m) apart.

    The footprint is the xy projection of the points on a grid of cell ``spacing``, closed and with holes
    filled; its boundary cells are extended from their lowest point down to the table."""
    lo = points[:, :2].min(axis=0) - 2 * spacing
    ij = np.floor((points[:, :2] - lo) / spacing).astype(int)
    shape = ij.max(axis=0) + 3
    occupied = np.zeros(shape, bool)
    occupied[ij[:, 0], ij[:, 1]] = True
    footprint = ndimage.binary_fill_holes(ndimage.binary_closing(occupied, iterations=2))
    boundary = footprint & ~ndimage.binary_erosion(footprint)

    on_boundary = boundary[ij[:, 0], ij[:, 1]]
    flat = ij[on_boundary, 0] * shape[1] + ij[on_boundary, 1]
    order = np.lexsort((points[on_boundary, 2], flat))
    first = np.r_[True, flat[order][1:] != flat[order][:-1]]
    lowest = points[on_boundary][order[first]]  # lowest point of each boundary cell
    walls = [np.column_stack([np.full(k, p[0]), np.full(k, p[1]), table_z + spacing * np.arange(k)])
             for p in lowest for k in [int(np.floor((p[2] - table_z) / spacing))] if k > 0]

    cells = np.argwhere(footprint)
    bottom = np.column_stack([lo + (cells + 0.5) * spacing, np.full(len(cells), table_z)])
    return np.vstack([points, *walls, bottom])


def fuse(views: Sequence[View], lo, hi, table_z: float = 0.0, voxel: float = 0.001,
         table_margin: float = 0.002, outlier_neighbours: int = 20, outlier_std: float = 2.0,
         register: bool = True, close: bool = True) -> np.ndarray:
    """Fused object cloud (n, 3) in m from camera ``views`` (SPEC §3.1).

    ``lo``, ``hi``: corners of the workspace box (m, base frame); ``table_z``: known table height (m);
    ``voxel``: downsampling voxel (m), also the spacing of the added bottom points; ``table_margin``:
    points less than this (m) above the levelled table are removed as table. ``register``: align the
    views by ICP (:func:`register_views`). With ``close=False`` the bottom is not added (the visible
    surface only). Raises ``ValueError`` if a view is unusable or
    nothing of the object remains."""
    if len(views) == 0:
        raise ValueError("fusion: no views given")
    kept = []
    for k, view in enumerate(views):
        pts = crop(check_points(view.in_base(), f"view {k}"), lo, hi)
        plane = fit_table(pts, table_z)
        if plane is None:
            raise ValueError(f"fusion: view {k} shows no table near z = {table_z} m inside the workspace")
        kept.append(voxel_downsample(remove_table(level_on_table(pts, plane, table_z), table_z, table_margin),
                                     voxel))
    if register and len(kept) > 1:
        kept = register_views(kept)
    merged = np.vstack(kept)
    if len(merged) < outlier_neighbours + 1:
        raise ValueError(f"fusion: only {len(merged)} object points remain after removing the table")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(voxel_downsample(merged, voxel)))
    cloud, _ = cloud.remove_statistical_outlier(outlier_neighbours, outlier_std)
    points = largest_cluster(np.asarray(cloud.points), eps=4 * voxel)
    return close_bottom(points, table_z, voxel) if close else points


__all__ = ["crop", "fit_table", "level_on_table", "remove_table", "register_views", "largest_cluster", "voxel_downsample",
           "SMOOTHING_NEIGHBOURS", "smooth_surface", "close_bottom", "fuse"]
