"""A prepared datapoint: everything identification needs from one (before, after) capture, after the
reconstruction stages. Stored as one ``.npz`` file. Lengths in m, robot base frame."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .effectors import Effector, by_name
from .losses import HeightMapTarget
from .motions import Trajectory
from .pointclouds import atomic_output
from .simulation import Scene


@dataclass
class Datapoint:
    """particles: the before object filled with particles (n, 3), each of volume ``particle_volume``
    (m³). trajectory / start: the resampled effector motion and the tip's start position (the top
    centre of the object unless the capture says otherwise). Targets of the after state: ``pcd_target``
    (down-sampled fused cloud), ``prt_target`` (particles filled in the after mesh, at most n), and
    ``heightmap`` (32 × 32 highest z, m) of the fused after cloud over the square centred at
    ``centre_xy``."""

    id: str
    motion: str
    effector: str
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

    def scene(self, effector: Effector | None = None) -> Scene:
        """The simulator scene; ``effector`` overrides the built-in one named by ``self.effector``."""
        return Scene(self.particles, self.particle_volume, effector or by_name(self.effector),
                     self.trajectory, self.start, self.table_z)


_ARRAYS = ("particles", "start", "pcd_target", "prt_target", "heightmap", "centre_xy")


def save_datapoint(path: str | Path, dp: Datapoint) -> None:
    """Write ``dp`` to ``path`` (.npz) atomically."""
    meta = {"id": dp.id, "motion": dp.motion, "effector": dp.effector,
            "particle_volume": dp.particle_volume, "table_z": dp.table_z, "dt": dp.trajectory.dt}
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, meta=json.dumps(meta), trajectory_positions=dp.trajectory.positions,
                                trajectory_yaw=dp.trajectory.yaw, **{k: getattr(dp, k) for k in _ARRAYS})


def load_datapoint(path: str | Path) -> Datapoint:
    """Read a datapoint written by :func:`save_datapoint`; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"prepared datapoint {path} does not exist; run the preparation stage first")
    try:
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            arrays = {k: np.asarray(data[k], dtype=float) for k in _ARRAYS}
            trajectory = Trajectory(data["trajectory_positions"], data["trajectory_yaw"], meta.pop("dt"))
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"{path} is not a prepared datapoint file: {err}") from err
    return Datapoint(trajectory=trajectory, **meta, **arrays)
