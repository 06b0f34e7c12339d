"""Simulator settings (fixed per process: changing them means new fields and kernels) and scenes
(changing per call: particles, trajectory, effector)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..effectors import Effector
from ..files import check_points
from ..heightmap import footprint_centre
from ..motions import DT, Trajectory
from ..parameters import STIFFEST, Parameters



WALL_CELLS = 3
"""Nodes this close to the box's faces stop outward motion (the box walls)."""

class SimulationError(RuntimeError):
    """A simulation could not run or went unstable; the message says where and with what parameters."""


@dataclass(frozen=True)
class SimulatorConfig:
    """Resolution and capacity of a simulator.

    dx: grid cell size (m). width, height: the simulated box (m) around the object: x and y span
    ``width`` centred on the object, z spans ``height`` above the table (plus three cells below).
    cfl: Courant number for the elastic wave speed; the substep count of a 0.01 s step is
    ceil(step_dt · c(θ) / (cfl · dx)), so every parameter value in range gets a stable step.
    max_particles / max_steps: capacities allocated once. substep_memory_mb: memory the forward pass
    may spend on keeping every substep's particle state, so that the backward pass need not recompute
    them from the per-step checkpoints (short motions fit; longer ones recompute).
    """

    dx: float = 0.006
    width: float = 0.21
    height: float = 0.10
    cfl: float = 0.7
    min_substeps: int = 8
    max_particles: int = 5000
    max_steps: int = 700
    step_dt: float = DT
    arch: str = "cpu"
    substep_memory_mb: float = 1200.0
    serial: bool | None = None
    """Run the particle and grid loops that scatter to the grid, and the light ones, on one thread (True)
    or on all (False: on the CPU the transfers then gather at the nodes, on a GPU they add atomically);
    None chooses by ``arch``: see :attr:`serial_loops`."""
    threads: int | None = None
    """CPU threads Taichi may run loops on (None: every CPU this process may run on). Like ``arch`` it is
    fixed by the first simulator of a process."""

    def __post_init__(self):
        if self.dx <= 0 or self.width <= 4 * self.dx or self.height <= 4 * self.dx:
            raise ValueError(f"simulator box {self.width}×{self.height} m is too small for cell {self.dx} m")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be at least 1 (or None for every CPU), got {self.threads}")
        if not 0 < self.cfl <= 1:
            raise ValueError(f"cfl must lie in (0, 1], got {self.cfl}")

    @property
    def serial_loops(self) -> bool:
        """Whether the scattering and light loops run on one thread: as ``serial`` says, or when it is
        None, on the CPU and not on a GPU (where one thread would do all the work). On several CPU threads
        the transfers gather at the nodes instead of scattering (atomic adds there cost more than the
        threads gain); on two threads that was as fast as one thread's scatters at 17 000 particles and
        slower at 2000 (docs/benchmarks.md), so the CPU's default stays one thread. The heavy loops without
        atomics (SVD and return mapping, the constitutive adjoint) use every thread either way."""
        return self.serial if self.serial is not None else self.arch == "cpu"

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        n_xy = int(math.ceil(self.width / self.dx))
        return n_xy, n_xy, int(math.ceil(self.height / self.dx)) + 3

    def substeps(self, params: Parameters) -> int:
        """Substeps per step for these parameters (explicit stability with margin ``cfl``)."""
        n = math.ceil(self.step_dt * params.p_wave_speed() / (self.cfl * self.dx))
        return max(self.min_substeps, n)

    def check_box(self, scene: "Scene") -> np.ndarray:
        """The grid's corner (m) for ``scene`` (its box centred on the particles' footprint, the table
        WALL_CELLS cells above its floor), after checking that the particles and the effector's tip stay
        inside the box (two cells from its faces); :class:`SimulationError` saying which leaves it."""
        shape = np.array(self.grid_shape)
        origin = np.array([*(scene.centre_xy - 0.5 * shape[0] * self.dx), scene.table_z - WALL_CELLS * self.dx])
        upper, lower = origin + (shape - 2) * self.dx, origin + 2 * self.dx
        box = (f"[{lower.round(4)}, {upper.round(4)}] m (simulator width {self.width:g} m in x and y, height "
               f"{self.height:g} m above the table)")
        outside = np.any((scene.particles < lower) | (scene.particles > upper), axis=1)
        if outside.any():
            first = scene.particles[outside][0]
            raise SimulationError(f"{outside.sum()} particles lie outside the simulated box {box} (e.g. "
                                  f"{first.round(4)}); the object is larger than the box allows or lies below the "
                                  "table")
        tips, _ = scene.tip_poses()
        margin = 2 * self.dx
        bad = np.any((tips[:, :2] < lower[:2] + margin) | (tips[:, :2] > upper[:2] - margin), axis=1)
        bad |= (tips[:, 2] < scene.table_z - self.dx) | (tips[:, 2] > upper[2])
        if bad.any():
            k = int(np.argmax(bad))
            raise SimulationError(f"the effector trajectory leaves the simulated box at step {k} (tip at "
                                  f"{tips[k].round(4)} m, box {box}); the object is too large or the motion goes "
                                  "too far for the box")
        return origin

    @property
    def max_substeps(self) -> int:
        """Substeps at the stiffest, lightest corner of the parameter range."""
        return self.substeps(STIFFEST)


@dataclass
class Scene:
    """One simulated experiment.

    particles: (n, 3) initial positions in the robot base frame (m); each has volume
    ``particle_volume`` (m³), i.e. 1 / particle density. trajectory: the effector tip offsets and
    yaw from ``start`` (m, the tip's initial position in the base frame). table_z: height of the
    table plane (m).
    """

    particles: np.ndarray
    particle_volume: float
    effector: Effector
    trajectory: Trajectory
    start: np.ndarray
    table_z: float = 0.0

    def __post_init__(self):
        self.particles = np.ascontiguousarray(check_points(self.particles, "scene particles"))
        self.start = np.asarray(self.start, dtype=np.float64).reshape(3)
        if not self.particle_volume > 0:
            raise ValueError(f"particle_volume must be positive, got {self.particle_volume}")

    @property
    def centre_xy(self) -> np.ndarray:
        """Centre of the simulated box: the middle of the particles' footprint (m)."""
        return footprint_centre(self.particles)

    def tip_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-step tip positions (n_steps + 1, 3) in the base frame and absolute yaw (rad)."""
        return self.start + self.trajectory.positions, self.effector.initial_yaw + self.trajectory.yaw
