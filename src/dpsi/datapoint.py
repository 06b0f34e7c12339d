"""A prepared datapoint: everything identification needs from one (before, after) capture, after the
reconstruction stages. Stored as one ``.npz`` file. Lengths in m, robot base frame."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .effectors import Effector
from .files import load_arrays, save_arrays
from .heightmap import interior_cells
from .losses import HeightMapTarget, simulated_heightmap
from .motions import Trajectory


@dataclass
class Datapoint:
    """particles: the before object filled with particles (n, 3), each of volume ``particle_volume``
    (m³). effector: the shape that made the motion (built-in or from the dataset's mesh). trajectory /
    start: the resampled effector motion and the tip's start position (the top centre of the object
    unless the capture says otherwise). Targets of the after state: ``pcd_target`` (down-sampled fused
    cloud), ``prt_target`` (particles filled in the after mesh, at most n), and ``heightmap`` (32 × 32
    highest z, m) of the fused after cloud over the square centred at ``centre_xy``. The simulator's
    scene of a datapoint is :func:`dpsi.identification.scene`."""

    id: str
    motion: str
    effector: Effector
    particles: np.ndarray
    particle_volume: float
    trajectory: Trajectory
    start: np.ndarray
    table_z: float
    pcd_target: np.ndarray
    prt_target: np.ndarray
    heightmap: np.ndarray
    centre_xy: np.ndarray

    @property
    def particle_size(self) -> float:
        """Side (m) of the cube each particle stands for: the fill lattice spacing."""
        return float(self.particle_volume) ** (1.0 / 3.0)

    def heightmap_target(self) -> HeightMapTarget:
        """The captured after height map as a loss target, with this datapoint's particle cubes."""
        return HeightMapTarget(self.heightmap, self.centre_xy, self.table_z, self.particle_size)

    def interior_heightmap_target(self) -> HeightMapTarget:
        """The captured after height map counted only inside the outlines of both the target and the before
        particles (one cell in from each): the outline is where reconstruction errors dominate."""
        target = self.heightmap_target()
        before = simulated_heightmap(self.particles, target)
        return target._replace(cells=interior_cells(self.heightmap, before, floor=self.table_z))

_ARRAYS = ("particles", "start", "pcd_target", "prt_target", "heightmap", "centre_xy", "trajectory_positions",
           "trajectory_yaw", "effector_sdf")


def save_datapoint(path: str | Path, dp: Datapoint) -> None:
    """Write ``dp`` to ``path`` (.npz) atomically."""
    e = dp.effector
    meta = {"id": dp.id, "motion": dp.motion, "particle_volume": dp.particle_volume, "table_z": dp.table_z,
            "dt": dp.trajectory.dt,
            "effector": {"name": e.name, "kind": e.kind, "size": list(e.size), "initial_yaw": e.initial_yaw,
                         "sdf_lower": list(e.sdf_lower), "sdf_spacing": e.sdf_spacing}}
    arrays = {k: getattr(dp, k) for k in _ARRAYS[:6]}
    save_arrays(path, meta, {**arrays, "trajectory_positions": dp.trajectory.positions,
                             "trajectory_yaw": dp.trajectory.yaw,
                             "effector_sdf": np.zeros(0) if e.sdf is None else e.sdf})


def load_datapoint(path: str | Path) -> Datapoint:
    """Read a datapoint written by :func:`save_datapoint`; errors name the file."""
    meta, arrays = load_arrays(path, _ARRAYS, "prepared datapoint", "prepare")
    arrays = {k: a.astype(float) for k, a in arrays.items()}
    trajectory = Trajectory(arrays.pop("trajectory_positions"), arrays.pop("trajectory_yaw"), meta.pop("dt"))
    shape = meta.pop("effector")
    sdf = arrays.pop("effector_sdf")
    effector = Effector(shape["name"], shape["kind"], tuple(shape["size"]), shape["initial_yaw"],
                        sdf if sdf.size else None, tuple(shape["sdf_lower"]), shape["sdf_spacing"])
    return Datapoint(trajectory=trajectory, effector=effector, **meta, **arrays)


def load_datapoint_sets(*path_lists: Sequence[str | Path]) -> list[list[Datapoint]]:
    """The datapoints of each list of paths, a path named in several lists read once: the lists then share that
    :class:`Datapoint` object, so a simulation of it in one set can stand for it in another."""
    loaded: dict[str | Path, Datapoint] = {}
    for path in (path for paths in path_lists for path in paths):
        if path not in loaded:
            loaded[path] = load_datapoint(path)
    return [[loaded[path] for path in paths] for paths in path_lists]
