"""Damaged shape files are refused, naming the file, before a reader sees them: face indices outside the
vertices, truncated PCD and XYZ clouds, a PLY whose faces PyMeshLab skips."""

import re
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from dpsi.pointclouds import read_mesh, read_points, write_mesh

BOX = o3d.geometry.TriangleMesh.create_box(0.03, 0.03, 0.02)
N = len(BOX.vertices)


def _obj_with_face(folder, corner: str):
    """The box as OBJ with the first corner of its first face replaced by ``corner``."""
    write_mesh(folder / "box.obj", BOX)
    lines = (folder / "box.obj").read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("f "))
    lines[k] = "f " + " ".join([corner, *lines[k].split()[2:]])
    (folder / "bad.obj").write_text("\n".join(lines) + "\n")
    return folder / "bad.obj", k + 1


def _ascii_ply(path, faces, face_properties=""):
    v = np.asarray(BOX.vertices)
    header = (f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\n"
              f"{face_properties}end_header\n")
    extra = " 1" if face_properties else ""
    path.write_text(header + "".join(f"{x} {y} {z}\n" for x, y, z in v)
                    + "".join(f"3 {a} {b} {c}{extra}\n" for a, b, c in faces))
    return path


@pytest.mark.parametrize("corner, message", [
    (str(N + 1), f"face refers to vertex {N + 1}, but the file has {N} vertices"),
    ("0", "face refers to vertex 0, which does not exist"),
    (f"-{N + 1}", re.escape(f"face refers to vertex -{N + 1}, which does not exist ({N} vertices precede it")),
    (f"{N + 1}/1/1", f"face refers to vertex {N + 1}"),
])
def test_obj_face_outside_the_vertices_is_named(tmp_path, corner, message):
    path, line = _obj_with_face(tmp_path, corner)
    with pytest.raises(ValueError, match=message) as err:
        read_mesh(path)
    assert str(err.value).startswith(f"{path}, line {line}: ")


def test_a_far_out_of_range_face_gives_a_message_not_a_crash(tmp_path):
    """Index 100000 crashed PyMeshLab (exit 139, no message)."""
    path, line = _obj_with_face(tmp_path, "100000")
    done = subprocess.run([sys.executable, "-c", "import sys; from dpsi.pointclouds import read_mesh\n"
                           "try:\n read_mesh(sys.argv[1])\nexcept ValueError as e:\n print(e); sys.exit(1)",
                           str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr[-2000:]
    assert f"{path}, line {line}: face refers to vertex 100000, but the file has {N} vertices" in done.stdout


def test_ply_face_outside_the_vertices_is_named(tmp_path):
    faces = np.asarray(BOX.triangles).copy()
    faces[4, 1] = N + 7
    path = _ascii_ply(tmp_path / "ascii.ply", faces)
    with pytest.raises(ValueError, match=rf"{path}: face 4 refers to vertex {N + 7}, but the file has {N} vertices"):
        read_mesh(path)
    write_mesh(tmp_path / "binary.ply", BOX)
    data = (tmp_path / "binary.ply").read_bytes()
    assert b"binary_little_endian" in data[:100] and b"property list uchar uint vertex_indices" in data[:400]
    start = data.index(b"end_header\n") + len(b"end_header\n")
    vertices_end = start + N * 3 * 8  # double x, y, z
    at = vertices_end + 2 * 13 + 1 + 4  # face 2 (uchar count + 3 uint), its second index
    (tmp_path / "binary.ply").write_bytes(data[:at] + (10**6).to_bytes(4, "little") + data[at + 4:])
    with pytest.raises(ValueError, match=rf"binary.ply: face 2 refers to vertex 1000000, but the file has {N} "):
        read_mesh(tmp_path / "binary.ply")


def test_ply_faces_pymeshlab_skips_are_not_read_as_a_point_cloud(tmp_path):
    """Faces whose MeshLab 'flags' mark them deleted (bit 1): PyMeshLab reads the vertices and no face."""
    path = _ascii_ply(tmp_path / "flags.ply", np.asarray(BOX.triangles), "property int flags\n")
    with pytest.raises(ValueError, match=f"{path}: the header declares 12 faces but PyMeshLab read none"):
        read_mesh(path)
    other = _ascii_ply(tmp_path / "quality.ply", np.asarray(BOX.triangles), "property float quality\n")
    assert len(read_mesh(other).triangles) == 12


CLOUD = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).normal(0, 0.02, (400, 3))))


@pytest.mark.parametrize("name, options, message", [
    ("ascii.pcd", {"write_ascii": True}, "truncated PCD file: the header declares 400 points but the file holds "
                                         r"\d+ complete rows"),
    ("binary.pcd", {}, r"truncated PCD file: the header declares 400 points \(4800 bytes\)"),
    ("compressed.pcd", {"compressed": True}, "truncated PCD file: its compressed data block is cut off"),
    ("cloud.xyz", {}, r"line \d+: '.*' is not three numbers x y z \(m\): the file is truncated"),
])
def test_truncated_cloud_is_refused(tmp_path, name, options, message):
    """Half of each file: Open3D read the ASCII PCD as 400 points padded with zeros, the XYZ as 200."""
    path = tmp_path / name
    assert o3d.io.write_point_cloud(str(path), CLOUD, **options)
    assert len(read_points(path)) == 400
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2 + 5])
    with pytest.raises(ValueError, match=message) as err:
        read_points(path)
    assert str(err.value).startswith(str(path))
