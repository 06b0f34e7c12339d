"""Import of the paper's published real clay data as a raw dataset (docs/raw-format.md).

Each pair that :func:`dpsi.release_plan.plan_rows` finds becomes a datapoint ``<id>/`` with
``before_mesh.obj`` and ``after_mesh.obj`` in the robot base frame (table z = 0; small scan defects repaired
and reported, :mod:`dpsi.reconstruction.repair`), and its own ``trajectory.csv``: the motion as planned
(the real trajectories are not published) with the tip starting at the top centre of the before mesh.

Pairs published ``_normalised`` were each centred on their own bounding box, so before and after share no
frame; they are aligned here: each mesh's lowest point on the table z = 0, and the after mesh's footprint
centre (bounding box in x, y) on the before mesh's.

Lengths in m.
"""

from __future__ import annotations

from pathlib import Path

import open3d as o3d

from dpsi.motions import get_motion, plan, write_waypoints
from dpsi.pointclouds import read_mesh, write_mesh
from dpsi.rawdata import RawDataError, write_datapoints_table
from dpsi.reconstruction.meshing import is_watertight
from dpsi.reconstruction.repair import Repair, repair_scan
from dpsi.release_plan import ImportTables, ReleaseError, plan_rows

TABLE_Z = 0.0
"""Table height (m) of the release's robot base frame."""


def table_aligned(before: o3d.geometry.TriangleMesh,
                  after: o3d.geometry.TriangleMesh) -> tuple[o3d.geometry.TriangleMesh, o3d.geometry.TriangleMesh]:
    """A normalised pair put into one frame: each mesh's lowest point on the table z = 0, and the after
    mesh's bounding-box centre in (x, y) on the before mesh's."""
    lo_b, hi_b = before.get_min_bound(), before.get_max_bound()
    lo_a, hi_a = after.get_min_bound(), after.get_max_bound()
    shift = (lo_b[:2] + hi_b[:2]) / 2 - (lo_a[:2] + hi_a[:2]) / 2
    return (o3d.geometry.TriangleMesh(before).translate([0.0, 0.0, TABLE_Z - lo_b[2]]),
            o3d.geometry.TriangleMesh(after).translate([shift[0], shift[1], TABLE_Z - lo_a[2]]))


def _closed(path: Path) -> tuple[o3d.geometry.TriangleMesh, list[Repair]]:
    mesh, repairs = repair_scan(read_mesh(path), str(path))
    if not is_watertight(mesh):
        raise RawDataError(f"{path}: mesh is not watertight, and mending it needs more than removing duplicated "
                           "or collapsed faces, closing holes of a few triangles and turning flipped faces")
    return mesh, repairs


def import_release(source: str | Path, out: str | Path, tables: ImportTables, seed: int = 0) -> list[dict]:
    """Write the raw dataset of the pairs under ``source`` that ``tables`` names into the folder ``out``
    (it must not hold a dataset yet) and return its datapoint rows, each with the pair's published place
    and the repairs made to its meshes."""
    out = Path(out)
    if (out / "datapoints.csv").exists():
        raise ReleaseError(f"{out}: already holds a raw dataset (datapoints.csv); import into a new folder")
    rows, records = [], []
    for row, pair in plan_rows(source, tables):
        (before, fixed_before), (after, fixed_after) = _closed(pair.before), _closed(pair.after)
        if pair.normalised:
            before, after = table_aligned(before, after)
        folder = out / row["id"]
        folder.mkdir(parents=True, exist_ok=True)
        write_mesh(folder / "before_mesh.obj", before)
        write_mesh(folder / "after_mesh.obj", after)
        lo, hi = before.get_min_bound(), before.get_max_bound()
        start = [*(lo[:2] + hi[:2]) / 2, hi[2]]
        write_waypoints(folder / "trajectory.csv", plan(get_motion(row["motion"]), seed, start_xyz=start))
        rows.append(row)
        records.append({**row, "published": pair.published, "normalised": pair.normalised,
                        "repairs": {"before": [r.as_dict() for r in fixed_before],
                                    "after": [r.as_dict() for r in fixed_after]}})
    write_datapoints_table(out / "datapoints.csv", rows)
    return records


__all__ = ["TABLE_Z", "table_aligned", "import_release"]
