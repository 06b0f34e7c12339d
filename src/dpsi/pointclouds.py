"""Reading and writing point clouds, triangle meshes and 4×4 rigid transforms, with validation.

Point clouds are ``np.ndarray`` of shape (n, 3) in metres, read from PLY, PCD or XYZ files (via Open3D)
or ``.npy`` arrays. Meshes are ``open3d.geometry.TriangleMesh`` read from OBJ or PLY. Transforms are
4×4 homogeneous matrices (translation in m) stored as text (4 rows of 4 numbers, separated by spaces or
commas) or ``.npy``. Every reader raises an error naming the file and the problem; every writer writes atomically
(:func:`dpsi.files.atomic_output`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
import pymeshlab

from dpsi.files import atomic_output, check_points
from dpsi.shape_files import check_obj, check_pcd, check_ply, check_xyz

CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".npy")
MESH_SUFFIXES = (".obj", ".ply")
TRANSFORM_SUFFIXES = (".txt", ".csv", ".npy")
RIGID_TOL = 1e-5
"""Largest allowed entry of |RᵀR − I| and |det R − 1| for a rigid transform."""


@dataclass(frozen=True)
class View:
    """One camera capture: ``points`` (n, 3) in the camera frame (m) and the 4×4 camera-to-base transform
    ``camera_to_base`` (as calibrated, so possibly a few millimetres off)."""

    points: np.ndarray
    camera_to_base: np.ndarray

    def in_base(self) -> np.ndarray:
        """The points (n, 3) in the robot base frame (m)."""
        return transform_points(self.camera_to_base, self.points)


def _existing(path: str | os.PathLike, suffixes: tuple[str, ...], what: str) -> Path:
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"{path}: unsupported {what} file type {path.suffix!r}; use one of {list(suffixes)}")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: {what} file not found")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: {what} file is empty")
    return path


def _load_npy(path: Path, what: str) -> np.ndarray:
    """The numeric array in a .npy file (never unpickled); ``ValueError`` naming the file otherwise."""
    try:
        a = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError):
        a = None
    if not isinstance(a, np.ndarray) or not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{path}: not a numeric .npy array (corrupt, or it holds text or Python objects); "
                         f"save the {what} with numpy.save from a float array")
    return a


def read_points(path: str | os.PathLike) -> np.ndarray:
    """Point cloud (n, 3) in m from a PLY, PCD, XYZ or NPY file."""
    path = _existing(path, CLOUD_SUFFIXES, "point-cloud")
    if path.suffix.lower() == ".npy":
        a = _load_npy(path, "(n, 3) points")
    else:
        {".ply": check_ply, ".pcd": check_pcd, ".xyz": check_xyz}[path.suffix.lower()](path)
        a = np.asarray(o3d.io.read_point_cloud(str(path)).points)
        if len(a) == 0:
            raise ValueError(f"{path}: no points could be read (file is empty or malformed)")
    return check_points(a, str(path))


def write_points(path: str | os.PathLike, points) -> None:
    """Write an (n, 3) cloud in m to a PLY, PCD, XYZ or NPY file (by suffix), atomically."""
    path = Path(path)
    if path.suffix.lower() not in CLOUD_SUFFIXES:
        raise ValueError(f"{path}: unsupported point-cloud file type; use one of {list(CLOUD_SUFFIXES)}")
    a = check_points(points, str(path))
    with atomic_output(path) as tmp:
        if path.suffix.lower() == ".npy":
            with open(tmp, "wb") as fh:
                np.save(fh, a)
        else:
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(a))
            if not o3d.io.write_point_cloud(str(tmp), cloud):
                raise OSError(f"{path}: Open3D failed to write the point cloud")


def read_mesh(path: str | os.PathLike) -> o3d.geometry.TriangleMesh:
    """Triangle mesh (vertices in m) from an OBJ or PLY file, vertices kept exactly as stored (read with
    PyMeshLab: Open3D's OBJ reader merges coincident vertices, which can break a closed mesh's
    topology); ``ValueError`` if it cannot be read, is truncated, has a face index outside its vertices
    (checked first: PyMeshLab can crash on one), has no triangles or non-finite vertices."""
    path = _existing(path, MESH_SUFFIXES, "mesh")
    counts = check_ply(path) if path.suffix.lower() == ".ply" else {"vertex": check_obj(path)}
    declared = counts.get("vertex", 0)
    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except pymeshlab.PyMeshLabException as e:
        raise ValueError(f"{path}: not a readable mesh ({str(e).strip()})") from None
    vertices, faces = ms.current_mesh().vertex_matrix(), ms.current_mesh().face_matrix()
    if len(faces) == 0 and counts.get("face", 0) > 0:
        raise ValueError(f"{path}: the header declares {counts['face']} faces but PyMeshLab read none (it drops "
                         "faces whose 'flags' property marks them deleted); export the mesh with only vertex_indices "
                         "on its faces")
    if len(faces) == 0:
        raise ValueError(f"{path}: no triangles could be read (file is empty, malformed or a point cloud)")
    if not np.isfinite(vertices).all() or len(vertices) != declared:
        raise ValueError(f"{path}: the file declares {declared} vertices but {len(vertices)} finite ones could be "
                         "read (non-finite or malformed vertex coordinates); fix the vertices and export it again")
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(faces))


def write_mesh(path: str | os.PathLike, mesh: o3d.geometry.TriangleMesh) -> None:
    """Write a triangle mesh to an OBJ or PLY file (by suffix), atomically."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh file type; use one of {list(MESH_SUFFIXES)}")
    if len(mesh.triangles) == 0:
        raise ValueError(f"{path}: refusing to write a mesh without triangles")
    with atomic_output(path) as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_triangle_uvs=False):
            raise OSError(f"{path}: Open3D failed to write the mesh")


def check_rigid(matrix, source: str = "transform", tol: float = RIGID_TOL) -> np.ndarray:
    """``matrix`` as a float 4×4 array if it is a rigid transform (orthonormal rotation with det +1,
    finite translation, last row 0 0 0 1); otherwise ``ValueError`` naming ``source`` and the defect."""
    T = np.asarray(matrix, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"{source}: expected a 4x4 matrix, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise ValueError(f"{source}: transform has non-finite entries")
    if np.abs(T[3] - [0, 0, 0, 1]).max() > tol:
        raise ValueError(f"{source}: last row must be 0 0 0 1, got {T[3].tolist()}")
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > tol:
        raise ValueError(f"{source}: rotation part is not orthonormal (max |RᵀR − I| = {err:.3g}); "
                         "the transform is not rigid")
    if abs(np.linalg.det(R) - 1.0) > tol:
        raise ValueError(f"{source}: rotation has determinant {np.linalg.det(R):.6g}, not +1 (a reflection)")
    return T


def read_transform(path: str | os.PathLike) -> np.ndarray:
    """Rigid 4×4 transform from a text (.txt/.csv) or .npy file, validated by :func:`check_rigid`."""
    path = _existing(path, TRANSFORM_SUFFIXES, "transform")
    if path.suffix.lower() == ".npy":
        T = _load_npy(path, "4x4 matrix")
    else:
        try:
            T = np.loadtxt(path, delimiter="," if path.suffix.lower() == ".csv" else None, ndmin=2)
        except (ValueError, OSError) as e:
            raise ValueError(f"{path}: not a readable 4x4 matrix ({e})") from None
    return check_rigid(T, str(path))


def write_transform(path: str | os.PathLike, matrix) -> None:
    """Write a rigid 4×4 transform as text (.txt space-, .csv comma-separated) or .npy, atomically."""
    path = Path(path)
    if path.suffix.lower() not in TRANSFORM_SUFFIXES:
        raise ValueError(f"{path}: unsupported transform file type; use one of {list(TRANSFORM_SUFFIXES)}")
    T = check_rigid(matrix, str(path))
    with atomic_output(path) as tmp:
        if path.suffix.lower() == ".npy":
            with open(tmp, "wb") as fh:
                np.save(fh, T)
        else:
            np.savetxt(tmp, T, fmt="%.17g", delimiter="," if path.suffix.lower() == ".csv" else " ")


def transform_points(matrix, points) -> np.ndarray:
    """Apply a 4×4 transform to (n, 3) points: R p + t."""
    T = np.asarray(matrix, dtype=float)
    return np.asarray(points, dtype=float) @ T[:3, :3].T + T[:3, 3]


__all__ = [
    "CLOUD_SUFFIXES", "MESH_SUFFIXES", "TRANSFORM_SUFFIXES", "RIGID_TOL", "View", "check_ply", "read_points",
    "write_points", "read_mesh", "write_mesh", "check_rigid", "read_transform",
    "write_transform", "transform_points",
]
