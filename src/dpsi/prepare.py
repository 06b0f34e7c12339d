"""Turning one raw datapoint into a prepared :class:`~dpsi.datapoint.Datapoint` (SPEC §3), stage by stage.

Stages, each usable alone (the workflow runs them as separate rules with files in between):

1. :func:`fuse_state` – camera views → closed fused cloud (skipped for a state given as a fused cloud);
2. :func:`dpsi.reconstruction.meshing.reconstruct_mesh` – fused cloud → watertight mesh (skipped for a
   state given as a mesh);
3. :func:`fill_particles` – before mesh → particles at a density;
4. :func:`after_targets` – PRT target, PCD target and height map of the after state;
5. :func:`trajectory_and_start` – the resampled planner trajectory and the tip's start;

:func:`assemble` making the datapoint of their outputs, and :func:`build_datapoint` /
:func:`prepare_datapoint` composing them in memory. The workflow's stage files are written and read
here (:func:`save_targets`, :func:`save_trajectory` and their readers), and the CLI takes the same path. The after state's *surface
points* (for the PCD target and the height map) are its full-resolution fused cloud, or, for a state
given only as a mesh, points sampled on the mesh (:func:`surface_points`). Units: metres, robot base frame.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from dpsi.datapoint import Datapoint
from dpsi.effectors import Effector
from dpsi.files import load_arrays, save_arrays
from dpsi.heightmap import footprint_centre, height_map
from dpsi.motions import Trajectory, read_waypoints, resample
from dpsi.pointclouds import View
from dpsi.rawdata import RawDatapoint, RawDataset, StateSource
from dpsi.reconstruction.filling import fill, pcd_target, prt_target
from dpsi.reconstruction.fusion import fuse, smooth_surface
from dpsi.reconstruction.meshing import reconstruct_mesh

SURFACE_SPACING = 0.001
"""Mean spacing (m) of the points sampled on a mesh given instead of a fused cloud (the fusion voxel)."""


def fuse_state(views: Sequence[View], workspace, table_z: float, name: str = "state") -> np.ndarray:
    """Closed fused cloud (n, 3) in m of one state's camera ``views`` (SPEC §3.1), cropped to the
    ``workspace`` box (lo, hi) in m with the table at z = ``table_z``; errors name ``name``."""
    if workspace is None:
        raise ValueError(f"{name}: fusing camera views needs a workspace box (lo, hi); set it in dataset.yaml")
    try:
        return fuse(views, *workspace, table_z=table_z)
    except ValueError as e:
        raise ValueError(f"{name}: {e}") from None


def surface_points(mesh: o3d.geometry.TriangleMesh, spacing: float = SURFACE_SPACING) -> np.ndarray:
    """Points (n, 3) in m spread uniformly over the surface of ``mesh``, about ``spacing`` m apart
    (one per spacing² of area). Deterministic."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    if len(f) == 0:
        raise ValueError("surface_points: the mesh has no triangles")
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    n = max(1, int(np.ceil(area.sum() / spacing**2)))
    rng = np.random.default_rng(0)
    tri = rng.choice(len(f), size=n, p=area / area.sum())
    u, w = rng.random(n), rng.random(n)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    return a[tri] + u[:, None] * (b[tri] - a[tri]) + w[:, None] * (c[tri] - a[tri])


def state_points(source: StateSource, workspace, table_z: float, name: str = "state", config=None) -> np.ndarray:
    """Surface points (n, 3) in m of one state: its fused views, its given fused cloud, or points
    sampled on its given mesh. Given the simulator's ``config``, a given cloud or mesh must fit its box
    (:func:`check_extent`, before anything is sampled or meshed)."""
    data = source.load()
    if config is not None and source.form == "fused":
        check_extent(data.max(axis=0) - data.min(axis=0), config, name)
    elif config is not None and source.form == "mesh":
        check_extent(data.get_max_bound() - data.get_min_bound(), config, name)
    if source.form == "mesh":
        return surface_points(data)
    return fuse_state(data, workspace, table_z, name) if source.form == "views" else data


def state_mesh(source: StateSource, points: np.ndarray, name: str = "state") -> o3d.geometry.TriangleMesh:
    """Watertight mesh of one state: its given mesh, or the ball-pivoting mesh of its surface ``points``."""
    return source.load() if source.form == "mesh" else reconstruct_mesh(points, name=name)


def reconstruct_state(source: StateSource, workspace, table_z: float, name: str = "state",
                      config=None) -> tuple[np.ndarray, o3d.geometry.TriangleMesh]:
    """Surface points and watertight mesh of one state, entering the reconstruction at the stage
    matching the form it is given in (views: fusion; fused cloud: meshing; mesh: as it is); ``config``
    as in :func:`state_points`."""
    points = state_points(source, workspace, table_z, name, config)
    return points, state_mesh(source, points, name)


def _volume(mesh: o3d.geometry.TriangleMesh) -> float:
    """Volume (m³) enclosed by a closed triangle mesh (divergence theorem)."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    return abs(float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum())) / 6.0


def _too_many(name: str, n: float, density: float, volume: float, capacity: int) -> ValueError:
    return ValueError(f"{name}: this density ({density:.3g} particles/m³) gives ~{n:.3g} particles in the "
                      f"{volume * 1e6:.3g} cm³ object, the simulator holds {capacity}: lower the density to at most "
                      f"~{capacity / volume:.2g} particles/m³ (--density, or reconstruction.density in the workflow "
                      "config) or raise the capacity (--max-particles, or simulator.max_particles)")


def check_extent(extent, config, name: str = "state") -> None:
    """``ValueError`` naming ``name`` if an object of ``extent`` (x, y, z) m is larger than the simulated box
    of ``config`` (``width`` × ``width`` × ``height`` m), suggesting millimetres when it is far larger."""
    extent = np.asarray(extent, dtype=float)
    box = np.array([config.width, config.width, config.height])
    if (extent > box).any():
        units = " — are the units millimetres? Shapes must be in metres" if extent.max() > 10 * box.max() else ""
        raise ValueError(f"{name}: the object is {extent.max():.3g} m across ({' × '.join(f'{e:.3g}' for e in extent)}"
                         f" m), larger than the simulated box {config.width:g} × {config.width:g} × "
                         f"{config.height:g} m{units}")


def check_fits(mesh: o3d.geometry.TriangleMesh, density: float, config, name: str = "before mesh") -> None:
    """Before filling: ``ValueError`` naming ``name`` if the object is larger than the simulated box of
    ``config`` (a :class:`~dpsi.simulation.SimulatorConfig`: ``width`` × ``width`` × ``height`` m) or if
    its volume × ``density`` is clearly more than ``config.max_particles`` (fill would allocate a lattice
    for nothing; the exact count is checked after filling)."""
    check_extent(mesh.get_max_bound() - mesh.get_min_bound(), config, name)
    volume = _volume(mesh)
    if volume * density > 2 * config.max_particles:
        raise _too_many(name, volume * density, density, volume, config.max_particles)


def fill_particles(mesh: o3d.geometry.TriangleMesh, density: float, name: str = "before mesh",
                   config=None) -> np.ndarray:
    """Particles (n, 3) in m filling ``mesh`` at ``density`` particles/m³ (SPEC §3.3); each stands for
    1/density m³. ``ValueError`` naming ``name`` if none fits, or, given the simulator's ``config``, if the
    object does not fit its box or the particles its capacity (:func:`check_fits`)."""
    if config is not None:
        check_fits(mesh, density, config, name)
    particles = fill(mesh, density)
    if len(particles) == 0:
        raise ValueError(f"{name}: no particles fit inside the mesh at {density:.4g} particles/m³")
    if config is not None and len(particles) > config.max_particles:
        raise _too_many(name, len(particles), density, _volume(mesh), config.max_particles)
    return particles


def density_holding(mesh: o3d.geometry.TriangleMesh, count: int, density: float, factor: float = 1.05,
                    tries: int = 100) -> float:
    """The lowest density ``density`` · ``factor``^j (j ≥ 1, particles/m³) at which filling ``mesh`` gives at
    least ``count`` particles; ``ValueError`` if none of ``tries`` steps does."""
    for _ in range(tries):
        density *= factor
        if len(fill(mesh, density)) >= count:
            return density
    raise ValueError(f"no density up to {density:.3g} particles/m³ fills the mesh with {count} particles")


@dataclass(frozen=True)
class AfterTargets:
    """Loss targets of the after state (SPEC §3.4–3.5): the PRT target (k, 3) and PCD target (m, 3) in m,
    and the 32 × 32 height map (m) centred at ``centre_xy`` (2,) m, empty cells at ``table_z`` (m)."""

    prt_target: np.ndarray
    pcd_target: np.ndarray
    heightmap: np.ndarray
    centre_xy: np.ndarray
    table_z: float


_TARGET_ARRAYS = ("prt_target", "pcd_target", "heightmap", "centre_xy")
_TRAJECTORY_ARRAYS = ("positions", "yaw", "start")


def after_targets(after_mesh: o3d.geometry.TriangleMesh, after_points: np.ndarray, particles: np.ndarray,
                  density: float, table_z: float, measured: bool) -> AfterTargets:
    """The targets of the after state: the PRT target (particles in ``after_mesh``, at most as many as
    ``particles``, starting at ``density`` particles/m³), the PCD target (``after_points``
    voxel-downsampled) and the height map of ``after_points`` centred on the footprint of ``particles``
    (:func:`target_heightmap`; ``measured``: the points come from cameras, not from a mesh)."""
    centre = footprint_centre(particles)
    prt, _ = prt_target(after_mesh, density, len(particles))
    return AfterTargets(prt, pcd_target(after_points), target_heightmap(after_points, centre, table_z, measured),
                        centre, float(table_z))


def target_heightmap(after_points: np.ndarray, centre_xy, table_z: float, measured: bool) -> np.ndarray:
    """The height map (m) of the after state's surface points (m) around ``centre_xy``, empty cells at
    ``table_z``. A cell holds its highest point (SPEC §3.5), so ``measured`` points (from cameras) are
    smoothed first (:func:`~dpsi.reconstruction.fusion.smooth_surface`): their depth noise would raise every
    cell. Points sampled on a mesh are used as they are."""
    return height_map(smooth_surface(after_points) if measured else after_points, centre_xy, floor=table_z)


def save_targets(path: str | os.PathLike, targets: AfterTargets) -> None:
    """Write the targets stage's file (.npz) atomically."""
    save_arrays(path, {"table_z": targets.table_z}, {k: getattr(targets, k) for k in _TARGET_ARRAYS})


def load_targets(path: str | os.PathLike) -> AfterTargets:
    """Read a file written by :func:`save_targets`."""
    meta, arrays = load_arrays(path, _TARGET_ARRAYS, "after-state targets", "targets")
    return AfterTargets(**{k: a.astype(float) for k, a in arrays.items()}, table_z=float(meta["table_z"]))


def save_trajectory(path: str | os.PathLike, trajectory: Trajectory, start) -> None:
    """Write the trajectory stage's file (.npz: resampled trajectory and the tip's start) atomically."""
    save_arrays(path, {"dt": trajectory.dt}, {"positions": trajectory.positions, "yaw": trajectory.yaw,
                                              "start": np.asarray(start, dtype=float)})


def load_trajectory(path: str | os.PathLike) -> tuple[Trajectory, np.ndarray]:
    """Read a file written by :func:`save_trajectory`: (trajectory, start (3,) in m)."""
    meta, a = load_arrays(path, _TRAJECTORY_ARRAYS, "trajectory", "trajectory")
    return Trajectory(a["positions"], a["yaw"], float(meta["dt"])), a["start"].astype(float)


def assemble(datapoint_id: str, motion: str, effector: Effector, particles: np.ndarray, density: float,
             trajectory: Trajectory, start, targets: AfterTargets) -> Datapoint:
    """The prepared datapoint from the outputs of the stages (particles at ``density`` particles/m³)."""
    return Datapoint(datapoint_id, motion, effector, particles, 1.0 / density, trajectory, np.asarray(start, float),
                     targets.table_z, targets.pcd_target, targets.prt_target, targets.heightmap, targets.centre_xy)


def trajectory_and_start(path: str | os.PathLike) -> tuple[Trajectory, np.ndarray]:
    """The planner trajectory in ``path`` resampled to 0.01 s steps, and the tip's start (3,) in m: its
    first waypoint, in the base frame."""
    waypoints = read_waypoints(path)
    return resample(waypoints), waypoints.xyz[0].copy()


def build_datapoint(datapoint: RawDatapoint, effector: Effector, before_mesh: o3d.geometry.TriangleMesh,
                    after_mesh: o3d.geometry.TriangleMesh, after_points: np.ndarray, density: float,
                    table_z: float) -> Datapoint:
    """The prepared datapoint from the reconstructed states: particles filled in ``before_mesh`` at
    ``density`` particles/m³, targets from ``after_mesh`` and the after surface points, and the
    trajectory of the raw ``datapoint``, made with ``effector``."""
    particles = fill_particles(before_mesh, density, f"{datapoint.id} before mesh")
    targets = after_targets(after_mesh, after_points, particles, density, table_z, datapoint.after.measured)
    trajectory, start = trajectory_and_start(datapoint.trajectory)
    return assemble(datapoint.id, datapoint.motion, effector, particles, density, trajectory, start, targets)


def prepare_datapoint(dataset: RawDataset, datapoint: str | RawDatapoint, density: float) -> Datapoint:
    """All stages in memory: the datapoint (an id or a row of ``dataset``) prepared at ``density``
    particles/m³."""
    if isinstance(datapoint, str):
        datapoint = dataset.datapoint(datapoint)
    _, before_mesh = reconstruct_state(datapoint.before, dataset.workspace, dataset.table_z, f"{datapoint.id} before")
    after_points, after_mesh = reconstruct_state(datapoint.after, dataset.workspace, dataset.table_z,
                                                 f"{datapoint.id} after")
    effector = dataset.effectors[datapoint.effector].effector()
    return build_datapoint(datapoint, effector, before_mesh, after_mesh, after_points, density, dataset.table_z)


__all__ = ["SURFACE_SPACING", "fuse_state", "surface_points", "state_points", "state_mesh", "reconstruct_state",
           "check_extent", "check_fits", "density_holding", "fill_particles", "AfterTargets", "after_targets",
           "target_heightmap",
           "save_targets", "load_targets", "save_trajectory", "load_trajectory", "trajectory_and_start", "assemble",
           "build_datapoint", "prepare_datapoint"]
