"""Height maps of point sets and their distance (SPEC §3.5).

A height map covers a ``size`` × ``size`` square (m) centred at ``centre_xy`` and cut into
``cells`` × ``cells`` half-open cells; ``map[i, j]`` is cell ``i`` along x and ``j`` along y,
both counted from the square's low corner. Each cell holds the highest z (m) of the points in
it; points outside the square are ignored.

Points may stand for particles: cubes of side ``particle_size`` (m, the lattice spacing
density^(-1/3) of a filled object) centred at the points. A particle then covers every cell its square
footprint overlaps, at the height of its cube's top (z + particle_size / 2), so that a filled object
leaves no empty cell inside its outline at any density (SPEC §3.5). ``particle_size`` 0 (the default)
treats points as points: a fused cloud, or surface samples.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

SIZE = 0.11
"""Side of the height-map square in m."""

CELLS = 32
"""Cells per side."""

TABLE_HEIGHT = 0.0
"""Default value (m) of empty cells: the table plane z = 0."""


def footprint_centre(particles) -> np.ndarray:
    """Middle (x, y) in m of the footprint of ``particles`` (n, 3): the centre of a datapoint's height
    maps and of the simulated box."""
    particles = np.asarray(particles, dtype=float)
    return 0.5 * (particles[:, :2].min(axis=0) + particles[:, :2].max(axis=0))


def _covered_cells(points: np.ndarray, corner: np.ndarray, cell: float, cells: int,
                   particle_size: float) -> tuple[np.ndarray, np.ndarray]:
    """(point index, flat cell index) of every map cell a point's footprint overlaps: the one cell it
    falls in for ``particle_size`` 0, else every cell its square of side ``particle_size`` overlaps."""
    lo = (points[:, :2] - corner - particle_size / 2) / cell
    first = np.floor(lo).astype(np.int64)
    last = np.maximum(first, np.ceil((points[:, :2] - corner + particle_size / 2) / cell).astype(np.int64) - 1)
    span = int(np.ceil(particle_size / cell)) + 1 if particle_size > 0 else 1
    index, flat = [], []
    for di in range(span):
        for dj in range(span):
            ij = first + (di, dj)
            keep = np.flatnonzero(np.all((ij <= last) & (ij >= 0) & (ij < cells), axis=1))
            index.append(keep)
            flat.append(ij[keep, 0] * cells + ij[keep, 1])
    return np.concatenate(index), np.concatenate(flat)


def height_map_owners(points, centre_xy, size: float = SIZE, cells: int = CELLS,
                      particle_size: float = 0.0) -> np.ndarray:
    """Index of the point holding each cell's highest z, shape (cells, cells); -1 for empty cells.

    ``points`` is (n, 3) in m, ``centre_xy`` (2,) in m, ``size`` and ``particle_size`` in m (see the
    module doc). A particle may hold several cells.
    """
    points = np.asarray(points, dtype=float)
    centre_xy = np.asarray(centre_xy, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {points.shape}")
    if centre_xy.shape != (2,):
        raise ValueError(f"centre_xy must have shape (2,), got {centre_xy.shape}")
    if not size > 0:
        raise ValueError(f"height-map size must be positive, got {size} m")
    if int(cells) != cells or cells < 1:
        raise ValueError(f"height-map cells must be a positive integer, got {cells}")
    if not (np.isfinite(particle_size) and particle_size >= 0):
        raise ValueError(f"particle size must be a non-negative length in m, got {particle_size}")
    cells = int(cells)

    index, flat = _covered_cells(points, centre_xy - size / 2, size / cells, cells, particle_size)
    order = np.lexsort((points[index, 2], flat))  # by cell, then by z ascending
    flat_sorted = flat[order]
    last = np.ones(len(flat_sorted), dtype=bool)  # marks the highest z of each cell
    last[:-1] = flat_sorted[1:] != flat_sorted[:-1]
    owners = np.full(cells * cells, -1, dtype=np.int64)
    owners[flat_sorted[last]] = index[order[last]]
    return owners.reshape(cells, cells)


def height_map(points, centre_xy, size: float = SIZE, cells: int = CELLS, floor: float | None = None,
               particle_size: float = 0.0) -> np.ndarray:
    """Height map (cells, cells) in m of ``points`` (n, 3) in m.

    Empty cells hold ``floor`` (m), by default :data:`TABLE_HEIGHT` (0.0, the table plane); with
    ``particle_size`` (m) > 0 each point is a particle cube covering its footprint up to its top.
    """
    owners = height_map_owners(points, centre_xy, size, cells, particle_size)
    return owned_heights(points, owners, floor, particle_size)


def owned_heights(points, owners: np.ndarray, floor: float | None = None, particle_size: float = 0.0) -> np.ndarray:
    """The height map (m) that ``owners`` (from :func:`height_map_owners` of the same ``points`` and
    ``particle_size``) describes: each owned cell at its point's z (plus ``particle_size`` / 2, the cube's
    top), empty cells at ``floor`` (default :data:`TABLE_HEIGHT`)."""
    heights = np.full(owners.shape, TABLE_HEIGHT if floor is None else float(floor))
    filled = owners >= 0
    heights[filled] = np.asarray(points, dtype=float)[owners[filled], 2] + particle_size / 2
    return heights


def interior_cells(*heights, floor: float, erosion: int = 1) -> np.ndarray:
    """Boolean mask (cells, cells) of the cells inside the outline of every one of the height maps
    ``heights`` (m): above ``floor`` (m) in each, then shrunk by ``erosion`` cells so that no cell on an
    outline is kept. The outline of a reconstructed object is where its shape errors concentrate
    (docs/identifiability.md); the interior is where a motion's dent and bulge are measured."""
    if not heights:
        raise ValueError("interior_cells needs at least one height map")
    inside = np.logical_and.reduce([np.asarray(h, dtype=float) > floor + 1e-9 for h in heights])
    return ndimage.binary_erosion(inside, iterations=erosion) if erosion > 0 else inside


def heightmap_distance_mm(a, b) -> float:
    """Distance Σ_ij |a_ij − b_ij| in mm between two height maps given in m."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"height maps differ in shape: {a.shape} vs {b.shape}")
    return float(np.abs(a - b).sum() * 1000.0)


__all__ = ["SIZE", "CELLS", "TABLE_HEIGHT", "height_map_owners", "height_map", "owned_heights", "interior_cells", "heightmap_distance_mm"]
