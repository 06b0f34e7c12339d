"""Loss landscapes (SPEC §7.1): training losses over a grid of two parameters, the others fixed — the
pairs, the grid axes, and the landscape data and its file. Computing one by simulation is
:mod:`dpsi.landscape_compute`.

A landscape of a pair (p, q) over a dataset holds, at every point of a ``resolution`` × ``resolution``
grid spanning both parameters' full ranges (:data:`~dpsi.parameters.LOWER` … :data:`~dpsi.parameters.UPPER`,
evenly spaced, SI units), each loss (mm) averaged over the dataset's datapoints.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dpsi.parameters import LOWER, NAMES, UPPER, Parameters
from dpsi.files import load_arrays, save_arrays

class Pair(NamedTuple):
    """Two parameters spanning a landscape (``first`` on the x axis, ``second`` on the y axis) and the
    contact-complexity level whose training datasets it is computed on."""

    first: str
    second: str
    level: int

    @property
    def name(self) -> str:
        """File-name form, e.g. ``"E-nu"``."""
        return f"{self.first}-{self.second}"


PAIRS = (Pair("E", "nu", 1), Pair("yield_stress", "rho", 1), Pair("mu_table", "mu_effector", 2))
"""The pairs of SPEC §7.1: (E, ν) and (σ_y, ρ) at level 1, (μ_t, μ_m) at level 2."""


AROUND_FIXED = (Pair("E", "yield_stress", 1),)
"""Pairs drawn around the fixed values (at :data:`SCAN_FACTORS` times them) instead of over the full ranges:
(E, σ_y), whose ranges span 30 and 20 times, and whose ratio the yield strain is what pokes determine."""

SCAN_FACTORS = (0.5, 0.7, 1.0, 1.4, 2.0, 4.0)
"""Multiples of the fixed value on the axes of the pairs around it."""


def scan_values(name: str, centre: float) -> np.ndarray:
    """Parameter ``name`` at :data:`SCAN_FACTORS` times ``centre`` (SI), those within its range."""
    return np.array([centre * f for f in SCAN_FACTORS if LOWER[name] <= centre * f <= UPPER[name]])


def pair_by_name(name: str) -> Pair:
    """The pair of :data:`PAIRS` or :data:`AROUND_FIXED` whose :attr:`Pair.name` is ``name``."""
    for pair in PAIRS + AROUND_FIXED:
        if pair.name == name:
            return pair
    raise ValueError(f"unknown parameter pair {name!r}; known pairs are {[p.name for p in PAIRS + AROUND_FIXED]}")


def grid_axes(pair: Pair, fixed: Parameters, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """The two axes (SI) of ``pair``'s landscape: around ``fixed`` for :data:`AROUND_FIXED`, else
    ``resolution`` values over each full range (:func:`axis`)."""
    if pair in AROUND_FIXED:
        return scan_values(pair.first, getattr(fixed, pair.first)), scan_values(pair.second, getattr(fixed, pair.second))
    return axis(pair.first, resolution), axis(pair.second, resolution)


def axis(name: str, resolution: int) -> np.ndarray:
    """``resolution`` (≥ 2) evenly spaced values spanning parameter ``name``'s full range, in its SI unit."""
    if name not in NAMES:
        raise ValueError(f"unknown parameter {name!r}; known parameters are {list(NAMES)}")
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 2:
        raise ValueError(f"resolution must be an integer of at least 2, got {resolution!r}")
    return np.linspace(LOWER[name], UPPER[name], resolution)


@dataclass(frozen=True)
class Landscape:
    """Losses over a grid: ``values[k, i, j]`` is loss ``losses[k]`` (mm, mean over the datapoints; NaN
    where a simulation failed) at ``pair.first = first[i]``, ``pair.second = second[j]``, every other
    parameter as in ``fixed``."""

    pair: Pair
    losses: tuple[str, ...]
    first: np.ndarray
    second: np.ndarray
    values: np.ndarray
    fixed: Parameters

    def __post_init__(self):
        expected = (len(self.losses), len(self.first), len(self.second))
        if self.values.shape != expected:
            raise ValueError(f"landscape values have shape {self.values.shape}, expected {expected} "
                             "(losses, first axis, second axis)")


def fixed_cell(landscape: Landscape) -> tuple[int, int]:
    """Grid indices (i, j) of the landscape's fixed values of its two parameters; an error if an axis does
    not hold its fixed value."""
    pair, fixed = landscape.pair, landscape.fixed
    index = []
    for name, values in ((pair.first, landscape.first), (pair.second, landscape.second)):
        hits = np.flatnonzero(np.isclose(values, getattr(fixed, name), rtol=1e-9, atol=0.0))
        if len(hits) != 1:
            raise ValueError(f"the landscape's {name} axis does not hold its fixed value {getattr(fixed, name):g}")
        index.append(int(hits[0]))
    return index[0], index[1]


_ARRAYS = ("first", "second", "values", "fixed")


def save_landscape(path: str | os.PathLike, landscape: Landscape) -> None:
    """Write ``landscape`` to ``path`` (.npz) atomically: arrays ``first``, ``second``, ``values``, ``fixed``
    (the six parameters in :data:`~dpsi.parameters.NAMES` order) and the metadata (pair, level, losses)."""
    pair = landscape.pair
    meta = {"first": pair.first, "second": pair.second, "level": pair.level, "losses": list(landscape.losses)}
    save_arrays(path, meta, {"first": landscape.first, "second": landscape.second, "values": landscape.values,
                             "fixed": landscape.fixed.as_array()})


def load_landscape(path: str | os.PathLike) -> Landscape:
    """Read a landscape written by :func:`save_landscape`; errors name the file."""
    meta, data = load_arrays(path, _ARRAYS, "landscape", "landscape")
    try:
        return Landscape(Pair(meta["first"], meta["second"], int(meta["level"])), tuple(meta["losses"]),
                         data["first"], data["second"], data["values"], Parameters.from_array(data["fixed"]))
    except (KeyError, ValueError) as err:
        raise ValueError(f"{path} is not a landscape file: {err}") from err


__all__ = ["Pair", "PAIRS", "AROUND_FIXED", "SCAN_FACTORS", "scan_values", "pair_by_name", "grid_axes", "axis", "Landscape", "fixed_cell", "save_landscape",
           "load_landscape"]
