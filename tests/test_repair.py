"""Repair of real scans' small mesh defects (dpsi.reconstruction.repair), as the raw-data reader uses it."""

import logging

import numpy as np
import open3d as o3d
import pytest

from conftest import shared
from dpsi.pointclouds import read_mesh, write_mesh
from dpsi.rawdata import RawDataError, read_closed_mesh
from dpsi.reconstruction.meshing import is_watertight, mesh_volume
from dpsi.reconstruction.repair import repair_scan


def _sphere():
    return o3d.geometry.TriangleMesh.create_sphere(0.02, 10)


def _with_faces(mesh, faces):
    return o3d.geometry.TriangleMesh(mesh.vertices, o3d.utility.Vector3iVector(np.asarray(faces)))


def test_one_face_listed_twice_where_a_triangle_is_missing_is_mended_and_reported(tmp_path, caplog):
    sphere = _sphere()
    faces = np.asarray(sphere.triangles).copy()
    missing = np.asarray(sphere.vertices)[faces[5]].mean(axis=0)
    faces[5] = faces[40]
    path = tmp_path / "scan.obj"
    write_mesh(path, _with_faces(sphere, faces))
    with caplog.at_level(logging.WARNING, logger="dpsi.repair"):
        mesh = read_closed_mesh(path)
    assert is_watertight(mesh) and len(mesh.triangles) == len(faces)
    assert mesh_volume(mesh) == pytest.approx(mesh_volume(sphere), rel=1e-5)  # OBJ keeps 6 decimals
    reported = {r.repair["what"]: r.repair for r in caplog.records}
    assert reported["duplicated face(s) removed"]["count"] == 1
    hole = reported["face(s) added to close holes"]
    assert hole["count"] == 1 and hole["file"] == str(path)
    assert np.allclose(hole["where_m"][0], missing, atol=1e-6)


def test_a_patch_wound_the_other_way_is_turned_back():
    sphere = _sphere()
    faces = np.asarray(sphere.triangles).copy()
    faces[[7, 8]] = faces[[7, 8], ::-1]
    mesh, repairs = repair_scan(_with_faces(sphere, faces))
    assert is_watertight(mesh) and len(mesh.triangles) == len(faces)
    assert [(r.what, r.count) for r in repairs] == [("face(s) re-oriented", 2)]


def test_a_mesh_with_a_large_hole_is_refused_naming_the_file(tmp_path):
    sphere = _sphere()
    faces = np.asarray(sphere.triangles)
    centres = np.asarray(sphere.vertices)[faces].mean(axis=1)
    path = tmp_path / "open.obj"
    write_mesh(path, _with_faces(sphere, faces[centres[:, 2] < 0.012]))
    with pytest.raises(RawDataError, match="open.obj.*not watertight"):
        read_closed_mesh(path)


def test_a_watertight_mesh_is_left_as_it_is():
    sphere = _sphere()
    mesh, repairs = repair_scan(sphere)
    assert mesh is sphere and repairs == []


def test_the_published_normalised_round_meshes_are_mended_within_a_few_percent_of_their_surface():
    for state in (0, 1):
        path = shared(f"real-clay/data-motion-poking-1/eef-round/mesh_2{state}.obj")
        original = read_mesh(path)
        mesh, repairs = repair_scan(original, str(path))
        assert not is_watertight(original) and is_watertight(mesh)
        assert {r.what for r in repairs} >= {"duplicated face(s) removed", "face(s) added to close holes"}
        assert mesh.get_surface_area() == pytest.approx(original.get_surface_area(), rel=0.05)
