"""Rigid end-effectors, described in their own frame: origin at the tip (lowest point), z up.

The three shapes of the paper are parametric signed-distance functions (SDFs); any watertight
OBJ can be used instead, sampled once into a signed-distance grid. Lengths are metres.
The simulator evaluates the SDFs (see :mod:`dpsi.simulation.contact`); this module only
holds the descriptions.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

BOX, BULLET, ROLLER, GRID = 0, 1, 2, 3
"""Shape kinds understood by the simulator."""

SDF_GRID_RESOLUTION = 40
"""Samples per axis of a mesh effector's signed-distance grid (fixed so that the simulator never recompiles)."""


@dataclass(frozen=True)
class Effector:
    """A rigid effector shape.

    ``size`` holds the shape's lengths in metres: BOX (width x, depth y, height z);
    BULLET (radius, height, 0); ROLLER (radius, length along y, shaft height).
    ``initial_yaw`` (rad) is the rotation about z at the start of every motion.
    For GRID shapes ``sdf`` is a (R, R, R) array of signed distances sampled at
    ``sdf_lower + spacing * index`` (negative inside).
    """

    name: str
    kind: int
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    initial_yaw: float = 0.0
    sdf: np.ndarray | None = field(default=None, compare=False, repr=False)
    sdf_lower: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sdf_spacing: float = 0.0

    @property
    def bounds(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Corners (m) of a box in the effector frame that contains the whole shape."""
        if self.kind == GRID:
            upper = np.asarray(self.sdf_lower) + self.sdf_spacing * (SDF_GRID_RESOLUTION - 1)
            return tuple(self.sdf_lower), tuple(map(float, upper))
        if self.kind == BOX:
            half = (self.size[0] / 2, self.size[1] / 2)
            return (-half[0], -half[1], 0.0), (half[0], half[1], self.size[2])
        if self.kind == BULLET:
            r = self.size[0]
            return (-r, -r, 0.0), (r, r, self.size[1])
        r = self.size[0]
        return (-r, -self.size[1] / 2, 0.0), (r, self.size[1] / 2, self.size[2])


RECTANGLE = Effector("rectangle", BOX, size=(0.03, 0.03, 0.06), initial_yaw=np.pi / 4)
"""30 × 30 mm square prism, 60 mm tall, pressing with its flat face; starts yawed 45°."""

ROUND = Effector("round", BULLET, size=(0.015, 0.06, 0.0))
"""Bullet: cylinder of radius 15 mm ending in a hemispherical tip, 60 mm tall."""

CYLINDER = Effector("cylinder", ROLLER, size=(0.015, 0.05, 0.06))
"""Roller: horizontal cylinder (radius 15 mm, 50 mm long, axis along y at z = 15 mm) on a vertical
shaft of radius 15 mm reaching z = 60 mm."""

BUILT_IN = {e.name: e for e in (RECTANGLE, ROUND, CYLINDER)}


def by_name(name: str) -> Effector:
    """The built-in effector called ``name`` (rectangle, round, cylinder)."""
    try:
        return BUILT_IN[name]
    except KeyError:
        raise ValueError(f"unknown effector {name!r}; known effectors are {sorted(BUILT_IN)}, "
                         "or give a watertight OBJ with effector_from_mesh") from None


def effector_from_mesh(path: str | Path, name: str | None = None, initial_yaw: float = 0.0,
                       margin: float = 0.005) -> Effector:
    """Sample a watertight triangle mesh (tip at its origin, metres) into a signed-distance grid."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"effector mesh {path} does not exist")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"effector mesh {path} has no triangles")
    mesh.remove_duplicated_vertices()
    if not mesh.is_watertight():
        raise ValueError(f"effector mesh {path} is not watertight; repair it (e.g. in MeshLab) before use")
    lower = np.asarray(mesh.get_min_bound()) - margin
    upper = np.asarray(mesh.get_max_bound()) + margin
    spacing = float(np.max(upper - lower) / (SDF_GRID_RESOLUTION - 1))
    axis = np.arange(SDF_GRID_RESOLUTION) * spacing
    points = np.stack(np.meshgrid(*(lower[i] + axis for i in range(3)), indexing="ij"), axis=-1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    sdf = scene.compute_signed_distance(points.reshape(-1, 3).astype(np.float32)).numpy()
    return Effector(name or path.stem, GRID, initial_yaw=initial_yaw,
                    sdf=sdf.reshape((SDF_GRID_RESOLUTION,) * 3).astype(np.float64),
                    sdf_lower=tuple(map(float, lower)), sdf_spacing=spacing)
