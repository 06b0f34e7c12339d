"""Reading and writing point clouds, triangle meshes and 4×4 rigid transforms, with validation.

Point clouds are ``np.ndarray`` of shape (n, 3) in metres, read from PLY, PCD or XYZ files (via Open3D)
or ``.npy`` arrays. Meshes are ``open3d.geometry.TriangleMesh`` read from OBJ or PLY. Transforms are
4×4 homogeneous matrices (translation in m) stored as text (4 rows of 4 numbers, separated by spaces or
commas) or ``.npy``. Every reader raises an error naming the file and the problem; every writer writes
a temporary file in the target folder and renames it, so a failed write never leaves a partial file.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
import pymeshlab

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


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike):
    """Yield a temporary path next to ``path`` (same suffix); on success rename it to ``path``,
    on any error delete it, so ``path`` is either complete or untouched."""
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{path}: cannot write, folder {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; give it the usual permissions
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _existing(path: str | os.PathLike, suffixes: tuple[str, ...], what: str) -> Path:
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"{path}: unsupported {what} file type {path.suffix!r}; use one of {list(suffixes)}")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: {what} file not found")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: {what} file is empty")
    return path


_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
              "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _ply_header(path: Path) -> tuple[str, list[tuple[str, int, list[tuple[int, ...]]]], bytes]:
    """Format, elements (name, count, properties: (size,) for a scalar, (count size, item size) for a
    list) and the data after the header of a PLY file; ``ValueError`` naming ``path`` if the header is bad."""
    raw = path.read_bytes()
    end = raw.find(b"end_header")
    newline = raw.find(b"\n", end)
    if not raw.startswith(b"ply") or end < 0 or newline < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' … 'end_header' header)")
    fmt, elements = "", []
    try:
        for line in raw[:end].decode("ascii").splitlines():
            words = line.split()
            if words[:1] == ["format"]:
                fmt = words[1]
            elif words[:1] == ["element"]:
                elements.append((words[1], int(words[2]), []))
            elif words[:2] == ["property", "list"]:
                elements[-1][2].append((_PLY_SIZES[words[2]], _PLY_SIZES[words[3]]))
            elif words[:1] == ["property"]:
                elements[-1][2].append((_PLY_SIZES[words[1]],))
    except (UnicodeDecodeError, IndexError, KeyError, ValueError) as e:
        raise ValueError(f"{path}: malformed PLY header ({type(e).__name__}: {e})") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"{path}: unknown PLY format {fmt!r}")
    return fmt, elements, raw[newline + 1:]


def _binary_rows_end(data: bytes, start: int, count: int, properties, byteorder: str) -> int:
    """Offset just past ``count`` binary rows of ``properties`` starting at ``start`` (beyond the data
    if it is too short)."""
    offset = start
    for _ in range(count):
        for prop in properties:
            if offset > len(data):
                return offset
            if len(prop) == 1:
                offset += prop[0]
            else:
                n = int.from_bytes(data[offset:offset + prop[0]], byteorder)
                offset += prop[0] + n * prop[1]
    return offset


def check_ply(path: str | os.PathLike) -> dict[str, int]:
    """The element counts of a PLY file (e.g. ``{"vertex": n, "face": m}``) after checking that its data
    holds everything its header declares; ``ValueError`` naming the file if it is truncated."""
    path = Path(path)
    fmt, elements, data = _ply_header(path)
    declared = {name: count for name, count, _ in elements}
    if fmt == "ascii":
        rows = sum(1 for line in data.splitlines() if line.strip())
        needed = sum(declared.values())
        if rows < needed:
            raise ValueError(f"{path}: truncated PLY file: the header declares {needed} rows "
                             f"({declared}) but the file holds {rows}; export it again")
        return declared
    byteorder = "little" if fmt == "binary_little_endian" else "big"
    offset = 0
    for name, count, properties in elements:
        if all(len(p) == 1 for p in properties):
            offset += count * sum(p[0] for p in properties)
        else:
            offset = _binary_rows_end(data, offset, count, properties, byteorder)
        if offset > len(data):
            raise ValueError(f"{path}: truncated PLY file: the header declares {count} {name} rows, which need "
                             f"more than the {len(data)} bytes of data the file holds; export it again")
    return declared


def check_points(points, source: str = "points") -> np.ndarray:
    """``points`` as a float (n, 3) array; ``ValueError`` naming ``source`` if empty, mis-shaped or
    non-finite."""
    a = np.asarray(points, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{source}: expected an (n, 3) array of points, got shape {a.shape}")
    if len(a) == 0:
        raise ValueError(f"{source}: contains no points")
    if not np.isfinite(a).all():
        raise ValueError(f"{source}: contains non-finite coordinates")
    return a


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
        if path.suffix.lower() == ".ply":
            check_ply(path)
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


def _check_obj_vertices(path: Path) -> int:
    """The number of vertices (``v`` lines) of an OBJ file; ``ValueError`` naming the file and line of a
    vertex that is not three finite numbers (a mesh reader would drop it and shift the faces)."""
    count = 0
    with open(path, errors="replace") as f:
        for number, line in enumerate(f, start=1):
            words = line.split()
            if words[:1] != ["v"]:
                continue
            try:
                xyz = [float(w) for w in words[1:4]]
            except ValueError:
                xyz = []
            if len(xyz) != 3 or not np.isfinite(xyz).all():
                raise ValueError(f"{path}, line {number}: vertex {' '.join(words[1:4])!r} is not three finite "
                                 "numbers (m); fix the vertex and export the mesh again")
            count += 1
    return count


def read_mesh(path: str | os.PathLike) -> o3d.geometry.TriangleMesh:
    """Triangle mesh (vertices in m) from an OBJ or PLY file, vertices kept exactly as stored (read with
    PyMeshLab: Open3D's OBJ reader merges coincident vertices, which can break a closed mesh's
    topology); ``ValueError`` if it cannot be read, has no triangles or non-finite vertices."""
    path = _existing(path, MESH_SUFFIXES, "mesh")
    declared = check_ply(path).get("vertex", 0) if path.suffix.lower() == ".ply" else _check_obj_vertices(path)
    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except pymeshlab.PyMeshLabException as e:
        raise ValueError(f"{path}: not a readable mesh ({str(e).strip()})") from None
    vertices, faces = ms.current_mesh().vertex_matrix(), ms.current_mesh().face_matrix()
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
    "CLOUD_SUFFIXES", "MESH_SUFFIXES", "TRANSFORM_SUFFIXES", "RIGID_TOL", "View", "atomic_output", "check_points",
    "check_ply", "read_points", "write_points", "read_mesh", "write_mesh", "check_rigid", "read_transform",
    "write_transform", "transform_points",
]
