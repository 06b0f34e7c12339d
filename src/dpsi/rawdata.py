"""The raw dataset a user drops under ``raw/<dataset>/`` and its up-front validation (docs/raw-format.md).

Layout (lengths in m, angles in rad, time in s, all poses in the robot base frame)::

    raw/<dataset>/
        datapoints.csv                 id,motion,effector,level,role,material
        dataset.yaml                   optional: table_z, workspace {lo, hi}, effectors {name: {kind|obj}}
        trajectories/<motion>.csv      planner trajectory t,x,y,z,yaw of each motion used
        <id>/trajectory.csv            optional: this datapoint's own planner trajectory (overrides)
        <id>/<state>/view_<k>.<ply|pcd|xyz|npy>            camera views, points in the camera frame ...
        <id>/<state>/view_<k>.transform.<txt|csv|npy>      ... each with its camera-to-base 4x4 transform
        <id>/<state>_fused.<ply|pcd|xyz|npy>                or: the fused, closed object cloud
        <id>/<state>_mesh.<obj|ply>                         or: a watertight mesh

``<state>`` is ``before`` or ``after``; each state is given in exactly one of the three forms and enters
the reconstruction at the matching stage (fusion, meshing, or filling).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from dpsi.dataset_yaml import EFFECTOR_KINDS, DatasetYamlError, EffectorSpec, read_dataset_yaml
from dpsi.datapoints_table import COLUMNS, TableError, read_table
from dpsi.motions import read_waypoints
from dpsi.pointclouds import (CLOUD_SUFFIXES, MESH_SUFFIXES, TRANSFORM_SUFFIXES, View, atomic_output,
                              check_points, check_rigid, read_mesh, read_points, read_transform, write_points,
                              write_transform)
from dpsi.reconstruction.meshing import is_watertight
from dpsi.reconstruction.repair import repair_scan

STATES = ("before", "after")
_VIEW = re.compile(r"^view_(\d+)$")


class RawDataError(ValueError):
    """The raw dataset is incomplete or malformed; the message names the file and the problem."""


@dataclass(frozen=True)
class StateSource:
    """Where one state (before/after) of a datapoint comes from: ``form`` 'views' (``paths`` are pairs
    (cloud, transform)), 'fused' or 'mesh' (``paths`` holds the one file)."""

    form: str
    paths: tuple

    def load(self):
        """The state's data: a list of :class:`~dpsi.pointclouds.View`, an (n, 3) cloud in m, or a mesh."""
        if self.form == "views":
            return [View(read_points(c), read_transform(t)) for c, t in self.paths]
        if self.form == "fused":
            return read_points(self.paths[0])
        return read_closed_mesh(self.paths[0])

    @property
    def measured(self) -> bool:
        """Whether the state's surface points come from cameras (with their depth noise), not from a mesh."""
        return self.form != "mesh"


@dataclass(frozen=True)
class RawDatapoint:
    """One row of the datapoints table with its planner ``trajectory`` file and the sources of its states."""

    id: str
    motion: str
    effector: str
    level: int
    role: str
    material: str
    trajectory: Path
    before: StateSource
    after: StateSource


@dataclass(frozen=True)
class RawDataset:
    """A validated raw dataset: ``table_z`` (m), workspace box corners ``workspace`` ((3,), (3,)) in m or
    ``None``, effectors by name and datapoints in table order."""

    root: Path
    table_z: float
    workspace: tuple[np.ndarray, np.ndarray] | None
    effectors: dict[str, EffectorSpec]
    datapoints: tuple[RawDatapoint, ...]

    def datapoint(self, datapoint_id: str) -> RawDatapoint:
        """The datapoint with this id; ``KeyError`` naming the dataset otherwise."""
        for datapoint in self.datapoints:
            if datapoint.id == datapoint_id:
                return datapoint
        raise KeyError(f"datapoint {datapoint_id!r} is not in the raw dataset {self.root}")


def _fail(path: Path, problem: str):
    raise RawDataError(f"{path}: {problem}")


def read_closed_mesh(path: str | os.PathLike):
    """The watertight mesh (m) in ``path``, its small scan defects repaired and logged
    (:func:`~dpsi.reconstruction.repair.repair_scan`); :class:`RawDataError` naming the file if it is not
    closed even then."""
    mesh, _ = repair_scan(read_mesh(path), str(path))
    if not is_watertight(mesh):
        _fail(Path(path), "mesh is not watertight (every edge must join exactly two consistently wound faces), and "
                          "mending it needs more than removing duplicated or collapsed faces, closing holes of a few "
                          "triangles and turning flipped faces; close its holes, or give the shape as a point cloud")
    return mesh


def read_dataset_config(root: str | os.PathLike) -> tuple[float, tuple | None, dict[str, EffectorSpec]]:
    """``root/dataset.yaml`` validated (:func:`~dpsi.dataset_yaml.read_dataset_yaml`, and each effector mesh
    read): table height (m), workspace box (lo, hi) in m or ``None``, and the effectors by name (the
    built-ins and the dataset's own)."""
    try:
        layout = read_dataset_yaml(root)
    except DatasetYamlError as e:
        raise RawDataError(str(e)) from None
    for name, spec in layout.effectors.items():
        if spec.obj is not None:
            try:
                mesh = read_mesh(spec.obj)
            except (OSError, ValueError) as e:
                _fail(Path(root) / "dataset.yaml", f"effector {name!r}: {e}")
            if not is_watertight(mesh):
                _fail(spec.obj, f"effector {name!r} mesh is not watertight")
    return layout.table_z, layout.workspace, layout.effectors


def _read_table(root: Path, effectors: dict[str, EffectorSpec]) -> pd.DataFrame:
    try:
        return read_table(root / "datapoints.csv", {name: spec.kind for name, spec in effectors.items()})
    except TableError as e:
        raise RawDataError(str(e)) from None


def _one(folder: Path, stem: str, suffixes: tuple[str, ...]) -> list[Path]:
    return [folder / f"{stem}{s}" for s in suffixes if (folder / f"{stem}{s}").is_file()]


def _state_source(folder: Path, state: str) -> StateSource:
    """Find and fully validate the one form in which ``state`` is given under the datapoint ``folder``."""
    views_dir = folder / state
    fused = _one(folder, f"{state}_fused", CLOUD_SUFFIXES)
    meshes = _one(folder, f"{state}_mesh", MESH_SUFFIXES)
    forms = [f for f, present in (("views", views_dir.is_dir()), ("fused", fused), ("mesh", meshes)) if present]
    if len(forms) != 1 or len(fused) > 1 or len(meshes) > 1:
        _fail(folder, f"the {state} state must be given in exactly one form ({state}/ views, one "
                      f"{state}_fused cloud or one {state}_mesh); found {forms or 'none'}")
    try:
        if forms == ["fused"]:
            read_points(fused[0])
            return StateSource("fused", (fused[0],))
        if forms == ["mesh"]:
            read_closed_mesh(meshes[0])
            return StateSource("mesh", (meshes[0],))
        pairs = []
        clouds = sorted((p for p in views_dir.iterdir() if _VIEW.match(p.name.split(".")[0])
                         and ".transform." not in p.name), key=lambda p: int(_VIEW.match(p.name.split(".")[0])[1]))
        for cloud in clouds:
            transforms = _one(views_dir, f"{cloud.name.split('.')[0]}.transform", TRANSFORM_SUFFIXES)
            if len(transforms) != 1:
                _fail(cloud, f"needs exactly one camera-to-base transform {cloud.name.split('.')[0]}.transform"
                             f"{{{','.join(TRANSFORM_SUFFIXES)}}}, found {len(transforms)}")
            read_points(cloud)
            read_transform(transforms[0])
            pairs.append((cloud, transforms[0]))
        if not pairs:
            _fail(views_dir, "contains no view_<k> point clouds")
        indices = sorted(int(_VIEW.match(c.name.split(".")[0])[1]) for c, _ in pairs)
        if indices != list(range(len(indices))):
            _fail(views_dir, f"views must be numbered view_0 … view_{len(indices) - 1} without gaps; "
                             f"found {indices}")
        return StateSource("views", tuple(pairs))
    except (OSError, ValueError) as e:
        if isinstance(e, RawDataError):
            raise
        raise RawDataError(str(e)) from None


def trajectory_file(root: str | os.PathLike, datapoint_id: str, motion: str) -> Path:
    """The planner trajectory of a datapoint: its own ``<id>/trajectory.csv`` if there is one, else the
    motion's ``trajectories/<motion>.csv``."""
    own = Path(root) / datapoint_id / "trajectory.csv"
    return own if own.is_file() else Path(root) / "trajectories" / f"{motion}.csv"


def load_raw_dataset(root: str | os.PathLike, only: Sequence[str] | None = None) -> RawDataset:
    """Validate the raw dataset under ``root`` (the table, and every file, cloud, transform, mesh and
    trajectory of its datapoints — or of the datapoints named in ``only`` — read once) and describe it.
    Raises :class:`RawDataError` naming the first bad file."""
    root = Path(root)
    if not root.is_dir():
        _fail(root, "raw dataset folder not found")
    table_z, workspace, effectors = read_dataset_config(root)
    df = _read_table(root, effectors)
    if only is not None:
        unknown = sorted(set(only) - set(df["id"]))
        if unknown:
            _fail(root / "datapoints.csv", f"has no datapoint(s) {unknown}")
        df = df[df["id"].isin(only)]
    datapoints = []
    checked_trajectories: set[Path] = set()
    for r in df.itertuples(index=False):
        folder = root / r.id
        if not folder.is_dir():
            _fail(folder, f"folder of datapoint {r.id} (listed in datapoints.csv) not found")
        trajectory = trajectory_file(root, r.id, r.motion)
        if trajectory not in checked_trajectories:
            try:
                read_waypoints(trajectory)
            except (OSError, ValueError) as e:
                raise RawDataError(f"{e} (planner trajectory of datapoint {r.id}, motion {r.motion})") from None
            checked_trajectories.add(trajectory)
        before, after = (_state_source(folder, s) for s in STATES)
        if "views" in (before.form, after.form) and workspace is None:
            _fail(root / "dataset.yaml", f"datapoint {r.id} has camera views, so a workspace box is needed "
                                         "for fusion (workspace: {lo: [x, y, z], hi: [x, y, z]})")
        datapoints.append(RawDatapoint(r.id, r.motion, r.effector, int(r.level), r.role, r.material,
                                       trajectory, before, after))
    return RawDataset(root, table_z, workspace, effectors, tuple(datapoints))


def write_checked(path: str | os.PathLike, dataset: RawDataset, datapoint_id: str) -> None:
    """Record (JSON, atomically) one datapoint of a validated ``dataset`` with what its stages need (its
    state sources, trajectory, effector, table height and workspace), so that they read its files without
    validating them again."""
    dp = dataset.datapoint(datapoint_id)
    source = lambda s: {"form": s.form, "paths": [[str(p) for p in item] if isinstance(item, tuple) else str(item)
                                                   for item in s.paths]}  # noqa: E731
    effector = dataset.effectors[dp.effector]
    record = {"root": str(dataset.root), "table_z": dataset.table_z,
              "workspace": None if dataset.workspace is None else [w.tolist() for w in dataset.workspace],
              "effector": {"name": effector.name, "kind": effector.kind,
                           "obj": None if effector.obj is None else str(effector.obj)},
              "datapoint": {**{k: getattr(dp, k) for k in ("id", "motion", "effector", "level", "role", "material")},
                            "trajectory": str(dp.trajectory), "before": source(dp.before), "after": source(dp.after)}}
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(record, indent=1))


def read_checked(path: str | os.PathLike) -> RawDataset:
    """The one-datapoint dataset recorded by :func:`write_checked` (its files not read again)."""
    try:
        record = json.loads(Path(path).read_text())
        source = lambda s: StateSource(s["form"], tuple(tuple(map(Path, p)) if isinstance(p, list) else Path(p)  # noqa: E731
                                                        for p in s["paths"]))
        d, e = record["datapoint"], record["effector"]
        datapoint = RawDatapoint(d["id"], d["motion"], d["effector"], int(d["level"]), d["role"], d["material"],
                                 Path(d["trajectory"]), source(d["before"]), source(d["after"]))
        effector = EffectorSpec(e["name"], e["kind"], None if e["obj"] is None else Path(e["obj"]))
        workspace = None if record["workspace"] is None else tuple(np.asarray(w, float) for w in record["workspace"])
        return RawDataset(Path(record["root"]), float(record["table_z"]), workspace, {effector.name: effector},
                          (datapoint,))
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise RawDataError(f"{path}: not a checked datapoint record ({e}); rerun the check_raw stage") from None


def write_views(folder: str | os.PathLike, views: list[View], suffix: str = ".ply",
                transform_suffix: str = ".txt") -> None:
    """Write camera ``views`` as ``view_<k><suffix>`` plus ``view_<k>.transform<transform_suffix>`` into
    ``folder`` (created if needed). Everything is validated before anything is written, and each file is
    written atomically."""
    folder = Path(folder)
    if not views:
        raise RawDataError(f"{folder}: no views to write")
    if suffix not in CLOUD_SUFFIXES or transform_suffix not in TRANSFORM_SUFFIXES:
        raise RawDataError(f"{folder}: unsupported view file types {suffix!r}, {transform_suffix!r}")
    try:
        for k, view in enumerate(views):
            check_points(view.points, str(folder / f"view_{k}{suffix}"))
            check_rigid(view.camera_to_base, str(folder / f"view_{k}.transform{transform_suffix}"))
    except ValueError as e:
        raise RawDataError(str(e)) from None
    folder.mkdir(parents=True, exist_ok=True)
    for k, view in enumerate(views):
        write_points(folder / f"view_{k}{suffix}", view.points)
        write_transform(folder / f"view_{k}.transform{transform_suffix}", view.camera_to_base)


def write_datapoints_table(path: str | os.PathLike, rows: list[dict]) -> None:
    """Write a datapoints table (columns id,motion,effector,level,role,material), atomically."""
    df = pd.DataFrame(rows)
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise RawDataError(f"{path}: rows lack column(s) {missing}")
    with atomic_output(path) as tmp:
        df[list(COLUMNS)].to_csv(tmp, index=False)


__all__ = ["STATES", "EFFECTOR_KINDS", "RawDataError", "StateSource", "EffectorSpec", "RawDatapoint", "RawDataset",
           "read_closed_mesh", "read_dataset_config", "trajectory_file", "load_raw_dataset", "write_checked",
           "read_checked", "write_views", "write_datapoints_table"]
