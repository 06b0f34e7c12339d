"""Synthetic twin of the real clay dataset: raw datapoints with known ground-truth parameters.

A twin lives in a raw dataset folder (docs/raw-format.md) and is made in two steps, so that a workflow
can run one job per datapoint:

1. :func:`write_twin_table` writes ``datapoints.csv`` (from a :data:`Plan`), ``dataset.yaml`` (table
   height, workspace) and ``truth.json``: the ground-truth parameters of each material and the generator
   settings (seed, simulator resolution, particle density).
2. :func:`generate_datapoint` makes one datapoint ``<id>/``: a random lump (:mod:`dpsi.shapes`) near
   :data:`CENTRE` filled with particles at a finer resolution than identification uses; the planner
   trajectory with the tip starting at the object's top centre (``trajectory.csv``); the motion
   simulated with the truth parameters; six noisy views with calibration error (``before/``,
   ``after/``) of both states, each captured as the watertight surface wrapped around its particles (so
   that, without motion, before and after look the same); and the ground truth (``truth.npz``,
   :func:`write_ground_truth`).

Everything is deterministic from the seed: each datapoint draws its randomness from (seed, id), so it
does not depend on which other datapoints are generated. Units: metres, seconds, SI parameters.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import open3d as o3d
import pandas as pd
import yaml

from dpsi.capture import capture
from dpsi.effectors import by_name
from dpsi.heightmap import height_map
from dpsi.motions import Trajectory, get_motion, plan, resample, write_waypoints
from dpsi.parameters import Parameters
from dpsi.files import atomic_output, load_arrays, save_arrays
from dpsi.prepare import surface_points
from dpsi.progress import Progress
from dpsi.rawdata import write_datapoints_table, write_views
from dpsi.reconstruction.filling import fill, lattice_spacing, particles_to_mesh
from dpsi.shapes import random_lump
from dpsi.simulation import Scene, Simulator, SimulatorConfig
from dpsi.twin_plan import MATERIALS, TRUTH_FILE, Plan, default_plan, load_truth, plan_rows

CENTRE = (-0.52, 0.01)
"""Where the lumps lie on the table (x, y in m, robot base frame), as in the published real data."""

CENTRE_JITTER = 0.005
"""Each lump's centre is moved by up to this much (m) in x and y."""

TABLE_Z = 0.0
WORKSPACE = ((-0.62, -0.09, -0.01), (-0.42, 0.11, 0.10))
"""Workspace box (lo, hi) in m kept by fusion: the lump, anything a motion pushes, and table around it."""

FINE_CONFIG = SimulatorConfig(dx=0.004, max_particles=22000)
"""Simulator of the twin: 4 mm cells (identification uses 6 mm) and room for the largest lump."""

FINE_DENSITY = 1.5e8
"""Particles/m³ of the twin's simulation (1.9 mm apart; identification uses 4e7–8e7)."""

GROUND_TRUTH_FILE = "truth.npz"


@dataclass(frozen=True)
class MotionError:
    """How far a twin's simulated motion strays from the path it records, as a robot's calibration error
    would: each datapoint's tool path is moved by a random translation, uniform within ±``translation`` m
    on each axis, and turned about its start by a random yaw within ±``yaw`` rad. Zero by default."""

    translation: float = 0.0
    yaw: float = 0.0

    def draw(self, seed: int) -> tuple[np.ndarray, float]:
        """The (translation (3,) in m, yaw in rad) of one datapoint, from ``seed``; zero if there is no error."""
        if self.translation == 0.0 and self.yaw == 0.0:
            return np.zeros(3), 0.0
        rng = np.random.default_rng(seed)
        return rng.uniform(-self.translation, self.translation, 3), float(rng.uniform(-self.yaw, self.yaw))


def turned_about_start(trajectory: Trajectory, yaw: float) -> Trajectory:
    """``trajectory`` turned about its start by ``yaw`` rad (positions rotated about z, yaw added)."""
    if yaw == 0.0:
        return trajectory
    c, s = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Trajectory(trajectory.positions @ rotation.T, trajectory.yaw + yaw, trajectory.dt)


def write_twin_table(root: str | os.PathLike, plan: Plan | None = None, seed: int = 0,
                     materials: dict[str, Parameters] | None = None, config: SimulatorConfig = FINE_CONFIG,
                     density: float = FINE_DENSITY, motion_error: MotionError | None = None) -> list[dict]:
    """Write ``datapoints.csv``, ``dataset.yaml`` and ``truth.json`` of a twin under ``root`` (created).

    ``plan`` defaults to :func:`default_plan`, ``materials`` (ground truth by name) to :data:`MATERIALS`;
    ``config`` and ``density`` (particles/m³) set the twin's simulation, ``motion_error`` how far the
    simulated motion strays from the recorded one (none by default). Returns the table rows."""
    root = Path(root)
    rows = plan_rows(default_plan() if plan is None else plan)
    materials = MATERIALS if materials is None else materials
    used = sorted({r["material"] for r in rows})
    unknown = sorted(set(used) - set(materials))
    if unknown:
        raise ValueError(f"no ground-truth parameters for material(s) {unknown}; known: {sorted(materials)}")
    lattice_spacing(density)  # validates the density
    root.mkdir(parents=True, exist_ok=True)
    write_datapoints_table(root / "datapoints.csv", rows)
    lo, hi = WORKSPACE
    with atomic_output(root / "dataset.yaml") as tmp:
        tmp.write_text(yaml.safe_dump({"table_z": TABLE_Z, "workspace": {"lo": list(lo), "hi": list(hi)}}))
    truth = {"seed": int(seed), "density": float(density), "simulator": asdict(config),
             "materials": {m: materials[m].as_dict() for m in used}}
    if motion_error is not None:
        truth["motion_error"] = asdict(motion_error)
    with atomic_output(root / TRUTH_FILE) as tmp:
        tmp.write_text(json.dumps(truth, indent=2))
    return rows


def read_truth(root: str | os.PathLike) -> tuple[dict[str, Parameters], int, SimulatorConfig, float, MotionError]:
    """Ground truth and generator settings of a twin: (parameters by material, seed, simulator config,
    density in particles/m³, motion error), from ``root/truth.json`` (:func:`dpsi.twin_plan.load_truth`)."""
    truth = load_truth(root)
    try:
        config = SimulatorConfig(**truth["simulator"])
    except (TypeError, ValueError) as e:
        raise ValueError(f"{Path(root) / TRUTH_FILE}: bad simulator settings ({e})") from None
    return truth["materials"], truth["seed"], config, truth["density"], MotionError(**truth["motion_error"])


@functools.cache
def simulator(config: SimulatorConfig) -> Simulator:
    """One simulator per configuration and process (compiling one takes seconds)."""
    return Simulator(config)


@dataclass
class GroundTruth:
    """What the twin knows about a datapoint: its ``material`` and ``parameters``, the simulated
    particles before and after the motion ((n, 3), m, each of volume ``particle_volume`` m³), the table
    height, and the height map (32 × 32, m) of the true after surface over the square centred at
    ``centre_xy``, the middle of the before particles' footprint."""

    id: str
    material: str
    parameters: Parameters
    particle_volume: float
    table_z: float
    before_particles: np.ndarray
    after_particles: np.ndarray
    centre_xy: np.ndarray
    heightmap: np.ndarray
    motion_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """How far (m) the simulated tool path was moved from the recorded one."""
    motion_yaw: float = 0.0
    """How far (rad) the simulated tool path was turned about its start from the recorded one."""


_GROUND_TRUTH_ARRAYS = ("before_particles", "after_particles", "centre_xy", "heightmap")


def write_ground_truth(path: str | os.PathLike, truth: GroundTruth) -> None:
    """Write ``truth`` to ``path`` (.npz) atomically."""
    meta = {"id": truth.id, "material": truth.material, "parameters": truth.parameters.as_dict(),
            "particle_volume": truth.particle_volume, "table_z": truth.table_z,
            "motion_offset": list(truth.motion_offset), "motion_yaw": truth.motion_yaw}
    save_arrays(path, meta, {k: getattr(truth, k) for k in _GROUND_TRUTH_ARRAYS})


def load_ground_truth(path: str | os.PathLike) -> GroundTruth:
    """Read a ground truth written by :func:`write_ground_truth`; errors name the file."""
    meta, arrays = load_arrays(path, _GROUND_TRUTH_ARRAYS, "twin ground-truth", "twin_datapoint")
    meta["parameters"] = Parameters.checked(**meta["parameters"])
    meta["motion_offset"] = tuple(meta.get("motion_offset", (0.0, 0.0, 0.0)))
    return GroundTruth(**meta, **{k: a.astype(float) for k, a in arrays.items()})


def _row(root: Path, datapoint_id: str) -> pd.Series:
    path = root / "datapoints.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: twin datapoints table not found; run write_twin_table first")
    table = pd.read_csv(path, dtype=str, keep_default_na=False)
    match = table[table["id"] == datapoint_id]
    if match.empty:
        raise KeyError(f"datapoint {datapoint_id!r} is not in {path}")
    return match.iloc[0]


def true_surface(particles: np.ndarray, spacing: float, name: str = "particles") -> o3d.geometry.TriangleMesh:
    """The surface (m) the twin's cameras see of its particles (n, 3) on a lattice of ``spacing`` m: their
    alpha wrap (:func:`~dpsi.reconstruction.filling.particles_to_mesh`) with vertices below the table raised
    onto it (the wrap's offset reaches under the lowest particles, which rest on the table or, after a
    motion, sink into it a little)."""
    mesh = particles_to_mesh(particles, spacing, name=name)
    v = np.asarray(mesh.vertices).copy()
    v[:, 2] = np.maximum(v[:, 2], TABLE_Z)
    mesh.vertices = o3d.utility.Vector3dVector(v)
    return mesh


def generate_datapoint(root: str | os.PathLike, datapoint_id: str) -> Path:
    """Generate datapoint ``datapoint_id`` of the twin under ``root`` (whose table and truth.json
    :func:`write_twin_table` wrote) and return its folder. The folder is built under a temporary name
    and renamed at the end, so it is either complete or absent."""
    root = Path(root)
    row = _row(root, datapoint_id)
    materials, seed, config, density, motion_error = read_truth(root)
    shape_seed, plan_seed, before_seed, after_seed, jitter_seed, error_seed = np.random.SeedSequence(
        [seed, zlib.crc32(datapoint_id.encode())]).generate_state(6)

    offset = np.random.default_rng(jitter_seed).uniform(-CENTRE_JITTER, CENTRE_JITTER, 2)
    particles = fill(random_lump(int(shape_seed), np.asarray(CENTRE) + offset, TABLE_Z), density)
    spacing = lattice_spacing(density)
    before = true_surface(particles, spacing, name=f"{datapoint_id} before")
    lo, hi = before.get_min_bound(), before.get_max_bound()
    waypoints = plan(get_motion(row.motion), int(plan_seed), start_xyz=[*(lo[:2] + hi[:2]) / 2, hi[2]])
    moved, turned = motion_error.draw(int(error_seed))
    scene = Scene(particles, 1.0 / density, by_name(row.effector), turned_about_start(resample(waypoints), turned),
                  waypoints.xyz[0] + moved, TABLE_Z)
    final = simulator(config).forward(scene, materials[row.material], keep_substeps=False)
    after = true_surface(final, spacing, name=f"{datapoint_id} after")
    centre_xy = scene.centre_xy
    truth = GroundTruth(datapoint_id, row.material, materials[row.material], 1.0 / density, TABLE_Z,
                        particles, final, centre_xy,
                        height_map(surface_points(after), centre_xy, floor=TABLE_Z), tuple(moved), turned)

    folder = root / datapoint_id
    tmp = root / f".{datapoint_id}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir()
        write_waypoints(tmp / "trajectory.csv", waypoints)
        write_views(tmp / "before", capture(before, TABLE_Z, seed=int(before_seed)))
        write_views(tmp / "after", capture(after, TABLE_Z, seed=int(after_seed)))
        write_ground_truth(tmp / GROUND_TRUTH_FILE, truth)
        shutil.rmtree(folder, ignore_errors=True)
        tmp.rename(folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def generate_twin(root: str | os.PathLike, plan: Plan | None = None, seed: int = 0,
                  materials: dict[str, Parameters] | None = None, config: SimulatorConfig = FINE_CONFIG,
                  density: float = FINE_DENSITY) -> list[Path]:
    """The whole twin in one process: :func:`write_twin_table`, then :func:`generate_datapoint` for each
    row. Returns the datapoint folders."""
    rows = write_twin_table(root, plan, seed, materials, config, density)
    folders = []
    with Progress(len(rows), "twin") as bar:
        for k, row in enumerate(rows, 1):
            folders.append(generate_datapoint(root, row["id"]))
            bar.update(k, row["id"])
    return folders


__all__ = ["CENTRE", "CENTRE_JITTER", "TABLE_Z", "WORKSPACE", "FINE_CONFIG", "FINE_DENSITY",
           "GROUND_TRUTH_FILE", "MotionError", "turned_about_start", "write_twin_table", "read_truth", "simulator", "true_surface", "GroundTruth", "write_ground_truth",
           "load_ground_truth", "generate_datapoint", "generate_twin"]
