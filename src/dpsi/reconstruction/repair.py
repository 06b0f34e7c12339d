"""Repair of the small defects that real scans carry, so that a nearly closed mesh can be filled.

A scanned and meshed object often has a face listed twice, a face collapsed to an edge, a few faces
overlapping on one edge, a hole of a few triangles where a face went missing, or a patch wound the other
way. :func:`repair_scan` mends these with the reconstruction's own repair
(:func:`dpsi.reconstruction.meshing.repair`, PyMeshLab for the holes and the winding) and reports each kind
of change: what, how many, and where (centres in m). A mesh that needs more than that (a patched area above
:data:`MAX_PATCHED_AREA` of its surface, or more than :data:`MAX_REMOVED_FACES` of its faces removed) is
returned unchanged, for the caller to refuse as not watertight.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import open3d as o3d
import pymeshlab

from dpsi.reconstruction.meshing import is_watertight, repair

MAX_HOLE_EDGES = 30
"""Holes bounded by at most this many edges are closed (the limit that matters is the area below)."""

MAX_PATCHED_AREA = 0.05
"""Largest area of the faces added to close holes, as a fraction of the mesh's surface area."""

MAX_REMOVED_FACES = 0.10
"""Largest fraction of the faces that a repair may remove (duplicates, collapsed and overlapping faces)."""

WHERE_SHOWN = 5
"""At most this many locations are reported per kind of repair."""

LOG = logging.getLogger("dpsi.repair")


@dataclass(frozen=True)
class Repair:
    """One kind of change made to a mesh: ``what`` (e.g. 'duplicated faces removed'), ``count`` and up to
    :data:`WHERE_SHOWN` locations ``where`` (x, y, z) in m."""

    what: str
    count: int
    where: tuple[tuple[float, float, float], ...]

    def as_dict(self) -> dict:
        return {"what": self.what, "count": self.count, "where_m": [list(p) for p in self.where]}

    def describe(self) -> str:
        places = "; ".join(f"({x:.4f}, {y:.4f}, {z:.4f})" for x, y, z in self.where)
        more = ", …" if self.count > len(self.where) else ""
        return f"{self.count} {self.what} at {places}{more} m"


def _faces_by_corners(mesh: o3d.geometry.TriangleMesh) -> tuple[list[tuple], np.ndarray, np.ndarray]:
    """Per face: its corners as a key independent of vertex numbering and order, its centre (m) and its
    unit normal."""
    v = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)]
    keys = [tuple(sorted(map(tuple, np.round(corners, 9)))) for corners in v]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    return keys, v.mean(axis=1), normal / np.where(length > 0, length, 1.0)


def _area(mesh: o3d.geometry.TriangleMesh, keep: np.ndarray | None = None) -> float:
    v = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)]
    areas = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    return float(areas.sum() if keep is None else areas[keep].sum())


def _where(centres: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    return tuple(tuple(round(float(c), 6) for c in centre) for centre in centres[:WHERE_SHOWN])


def _wound_coherently(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    """``mesh`` with its faces turned to agree with their neighbours (PyMeshLab), before the repair would
    drop the faces along a winding seam; as it is where PyMeshLab cannot (edges shared by more than two
    faces, which the repair removes first)."""
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles)))
    try:
        ms.meshing_re_orient_faces_coherently()
    except pymeshlab.PyMeshLabException:
        return mesh
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(ms.current_mesh().vertex_matrix()),
                                     o3d.utility.Vector3iVector(ms.current_mesh().face_matrix()))


def _compare(original: o3d.geometry.TriangleMesh, repaired: o3d.geometry.TriangleMesh) -> dict[str, list[int]]:
    """Indices of the faces of ``original`` that were duplicates ('duplicated') or are gone ('removed'), and
    of the faces of ``repaired`` that are new ('added') or wound the other way ('turned', counted against
    the majority: turning the whole mesh inside out is no repair)."""
    keys, _, normals = _faces_by_corners(original)
    new_keys, _, new_normals = _faces_by_corners(repaired)
    first: dict[tuple, int] = {}
    duplicated = [k for k, key in enumerate(keys) if first.setdefault(key, k) != k]
    index = {key: k for k, key in enumerate(new_keys)}
    kept = [(first[key], k) for key, k in index.items() if key in first]
    turned = [new for old, new in kept if normals[old] @ new_normals[new] < 0]
    if len(turned) > len(kept) / 2:
        turned = [new for old, new in kept if normals[old] @ new_normals[new] >= 0]
    return {"duplicated": duplicated, "removed": [k for key, k in first.items() if key not in index],
            "added": [k for k, key in enumerate(new_keys) if key not in first], "turned": turned}


WHAT = {"duplicated": ("duplicated face(s) removed", False),
        "removed": ("face(s) removed (collapsed, overlapping on an edge shared by more than two faces, or apart "
                    "from the main surface)", False),
        "added": ("face(s) added to close holes", True),
        "turned": ("face(s) re-oriented", True)}
"""Each kind of change: its description, and whether its indices are faces of the repaired mesh."""


def repair_scan(mesh: o3d.geometry.TriangleMesh, source: str = "mesh") -> tuple[o3d.geometry.TriangleMesh, list[Repair]]:
    """``mesh`` with its small scan defects mended and the list of changes (each logged naming ``source``);
    a watertight mesh comes back as it is with no changes. If the mended mesh is still not watertight, or the
    repair would patch more than :data:`MAX_PATCHED_AREA` of the surface or remove more than
    :data:`MAX_REMOVED_FACES` of the faces, the original comes back (with no changes) for the caller to
    refuse."""
    if is_watertight(mesh):
        return mesh, []
    repaired = repair(_wound_coherently(mesh), max_hole_edges=MAX_HOLE_EDGES)
    if not is_watertight(repaired):
        return mesh, []
    found = _compare(mesh, repaired)
    removed = len(found["duplicated"]) + len(found["removed"])
    if (_area(repaired, found["added"]) > MAX_PATCHED_AREA * _area(repaired)
            or removed > MAX_REMOVED_FACES * len(mesh.triangles)):
        return mesh, []
    centres = {False: _faces_by_corners(mesh)[1], True: _faces_by_corners(repaired)[1]}
    made = []
    for kind, faces in found.items():
        what, in_repaired = WHAT[kind]
        if faces:
            made.append(Repair(what, len(faces), _where(centres[in_repaired][faces])))
            LOG.warning("%s: repaired: %s", source, made[-1].describe(),
                        extra={"repair": {"file": source, **made[-1].as_dict()}})
    return repaired, made


__all__ = ["MAX_HOLE_EDGES", "MAX_PATCHED_AREA", "MAX_REMOVED_FACES", "Repair", "repair_scan"]
