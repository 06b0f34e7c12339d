"""Where the robot really went: a datapoint's motion offset, found by registering its dent in the scans.

On a real rig the effector's path in the camera frame is off by millimetres (hand-eye calibration), and the
planned path the simulation follows is not the path the robot took. Left alone, identification absorbs the
difference into the material (a dent 4 mm shallower than simulated reads as a clay that springs back more).

Clay keeps the shape of the tool that pressed it, so the dent in the after scan shows where the tool went,
almost whatever the material. :func:`register` simulates the datapoint along its planned path (at given,
e.g. hand-picked, parameters), draws the simulated and the scanned after states as fine height maps, and
finds the shift (dx, dy) of the scanned map that best matches the simulated imprint (every cell the motion
moved by more than :data:`MOVED`), and the height difference dz of the dent floor (cells pressed down).
The tool path is then moved by (dx, dy, dz) and the datapoint simulated again, until the offset changes
by less than :data:`CONVERGED` (at most :data:`ROUNDS` simulations). Of the paths simulated, the planned one
included, the one whose after state is closest to the scan by the height-map distance is kept: where the
dent does not show where the tool went (a flat press wider than the lump), the planned path stays. The
offset is a translation of the whole path; a yaw error is not estimated.

Because the dent is registered before identification and at fixed parameters, the offset is not traded
against the material during identification: depth is explained by the path, the material by the shape.

Lengths in m.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from dpsi.datapoint import Datapoint
from dpsi.heightmap import SIZE, height_map, heightmap_distance_mm
from dpsi.identification import scene
from dpsi.losses import simulated_heightmap
from dpsi.parameters import Parameters
from dpsi.simulation import Simulator

CELL = 0.001
"""Cell of the registration height maps (m), finer than the loss's 3.4 mm."""

MOVED = 0.001
"""A cell is part of the imprint if the simulated motion moved its surface by more than this (m)."""

SEARCH = 0.008
"""Largest shift (m) searched in x and y per round."""

STEP = 0.0005
"""Step (m) of the shift search."""

ROUNDS = 6
"""Most simulations per registration."""

CONVERGED = 0.0002
"""A round that changes the offset by less than this (m) ends the registration."""

LOG = logging.getLogger("dpsi.motion_offsets")


def shifted(dp: Datapoint, offset) -> Datapoint:
    """``dp`` with its tool path moved by ``offset`` (3,) m."""
    return dataclasses.replace(dp, start=np.asarray(dp.start, float) + np.asarray(offset, float))


def fine_map(points: np.ndarray, dp: Datapoint) -> np.ndarray:
    """Height map (m) of ``points`` drawn as ``dp``'s particle cubes over its square, at :data:`CELL`."""
    return height_map(points, dp.centre_xy, size=SIZE, cells=round(SIZE / CELL), floor=dp.table_z,
                      particle_size=dp.particle_size)


def imprint_shift(before: np.ndarray, simulated: np.ndarray, scanned: np.ndarray) -> np.ndarray:
    """The (dx, dy, dz) in m that moves the ``simulated`` after map's dent onto the ``scanned`` one (maps
    at :data:`CELL`; ``before`` the unmoved state). The dent of a map is how far each cell was pressed
    down, max(before − after, 0): (dx, dy) is the shift of the scanned dent that best matches the simulated
    one (least squares over a grid of shifts), dz the mean height difference of the two after maps over the
    simulated dent's cells at that shift."""
    pressed_sim = np.maximum(before - simulated, 0.0)
    dent = pressed_sim > MOVED
    if not dent.any():
        raise ValueError("the simulated motion presses no cell of the object down by more than "
                         f"{MOVED * 1e3:g} mm: there is no dent to register")
    pressed_scan = np.maximum(before - scanned, 0.0)
    best = (np.inf, np.zeros(3))
    steps = np.arange(-SEARCH, SEARCH + STEP / 2, STEP)
    for dx in steps:
        for dy in steps:
            # the scanned maps sampled at x + d: a dent made d away from the planned one lands on it
            there = (-dx / CELL, -dy / CELL)
            cost = np.mean((ndimage.shift(pressed_scan, there, order=1, mode="nearest") - pressed_sim) ** 2)
            if cost < best[0]:
                dz = np.mean((ndimage.shift(scanned, there, order=1, mode="nearest") - simulated)[dent])
                best = (cost, np.array([dx, dy, dz]))
    return best[1]


@dataclass(frozen=True)
class Registration:
    """A datapoint's motion offset (m, (3,)): of the offsets simulated (the planned path first, then one per
    round), the one whose after state is closest to the scanned one by the height-map distance; each with
    that distance (mm)."""

    id: str
    offset: np.ndarray
    tried: tuple[tuple[tuple[float, float, float], float], ...]

    def as_dict(self) -> dict:
        return {"id": self.id, "offset_m": self.offset.tolist(),
                "tried": [{"offset_m": list(o), "heightmap_mm": mm} for o, mm in self.tried]}


def register(simulator: Simulator, dp: Datapoint, params: Parameters) -> Registration:
    """The motion offset of ``dp`` (see module doc), simulated with ``params``; logged. The planned path
    is one of the candidates, so registration never moves a datapoint's path where it fits its scan worse."""
    before = fine_map(dp.particles, dp)
    scanned = fine_map(dp.prt_target, dp)
    offset, tried = np.zeros(3), []
    for _ in range(ROUNDS):
        final = simulator.forward(scene(shifted(dp, offset)), params, keep_substeps=False)
        distance = heightmap_distance_mm(simulated_heightmap(final, dp.heightmap_target()), dp.heightmap)
        tried.append((tuple(float(v) for v in offset), float(distance)))
        step = imprint_shift(before, fine_map(final, dp), scanned)
        if np.linalg.norm(step) < CONVERGED:
            break
        offset = offset + step
    best = np.array(min(tried, key=lambda t: t[1])[0])
    LOG.info("%s: motion offset (%.2f, %.2f, %.2f) mm of %d simulated", dp.id, *(best * 1e3), len(tried))
    return Registration(dp.id, best, tuple(tried))


__all__ = ["CELL", "MOVED", "SEARCH", "STEP", "ROUNDS", "CONVERGED", "shifted", "fine_map", "imprint_shift",
           "Registration", "register"]
