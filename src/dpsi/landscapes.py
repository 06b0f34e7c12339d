"""Loss landscapes (SPEC §7.1): training losses over a grid of two parameters, the others fixed.

A landscape of a pair (p, q) over a dataset holds, at every point of a ``resolution`` × ``resolution``
grid spanning both parameters' full ranges (:data:`~dpsi.parameters.LOWER` … :data:`~dpsi.parameters.UPPER`,
evenly spaced, SI units), each loss (mm) averaged over the dataset's datapoints. Every loss is a function
of the final particle positions, so one forward simulation per grid point and datapoint serves all of them.
All four other parameters come from the fixed values, at level 1 too (the twin's clay has the frictions
that level-1 identification holds fixed, so with its truth the two agree).

A grid point at which a datapoint's simulation fails (:class:`~dpsi.simulation.SimulationError`, e.g. an
instability) is NaN for every loss; if every grid point fails, the landscape is refused with the first
error, since that points to a problem of the setup (capacity, box) rather than of the parameters.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple, Sequence

import numpy as np

from dpsi.losses import loss_by_name
from dpsi.parameters import LOWER, NAMES, UPPER, Parameters
from dpsi.pointclouds import atomic_output

if TYPE_CHECKING:  # importing the simulator at run time would load Taichi, which reading a landscape does not need
    from dpsi.datapoint import Datapoint
    from dpsi.simulation import Simulator

log = logging.getLogger(__name__)


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


def pair_by_name(name: str) -> Pair:
    """The pair of :data:`PAIRS` whose :attr:`Pair.name` is ``name``."""
    for pair in PAIRS:
        if pair.name == name:
            return pair
    raise ValueError(f"unknown parameter pair {name!r}; known pairs are {[p.name for p in PAIRS]}")


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


def mean_losses(simulator: Simulator, datapoints: Sequence[Datapoint], params: Parameters,
                losses: Sequence[str]) -> np.ndarray:
    """Each loss (mm) averaged over ``datapoints`` simulated with ``params``, shape (len(losses),);
    raises :class:`SimulationError` if a simulation fails."""
    from dpsi.identification import targets

    functions = [loss_by_name(name) for name in losses]
    per_datapoint = []
    for dp in datapoints:
        final = simulator.forward(dp.scene(), params, keep_substeps=False)
        per_datapoint.append([f(final, targets(dp))[0] for f in functions])
    return np.mean(per_datapoint, axis=0)


def compute(simulator: Simulator, datapoints: Sequence[Datapoint], pair: Pair, fixed: Parameters,
            resolution: int, losses: Sequence[str]) -> Landscape:
    """The landscape of ``losses`` over ``pair`` (``resolution`` values per axis) on ``datapoints``, the
    other parameters at ``fixed`` (see the module doc for failures)."""
    from dpsi.simulation import SimulationError

    if not datapoints:
        raise ValueError("a landscape needs at least one datapoint")
    for name in losses:
        loss_by_name(name)
    first, second = axis(pair.first, resolution), axis(pair.second, resolution)
    values = np.full((len(losses), resolution, resolution), np.nan)
    errors = []
    for i, x in enumerate(first):
        for j, y in enumerate(second):
            params = fixed.replace(**{pair.first: x, pair.second: y})
            try:
                values[:, i, j] = mean_losses(simulator, datapoints, params, losses)
            except SimulationError as err:
                errors.append(err)
                log.warning("%s=%g, %s=%g: simulation failed, cell left NaN: %s", pair.first, x, pair.second, y, err)
                continue
            log.info("%s=%g, %s=%g: %s", pair.first, x, pair.second, y,
                     ", ".join(f"{n} {v:.1f} mm" for n, v in zip(losses, values[:, i, j])))
    if len(errors) == resolution * resolution:
        raise SimulationError(f"every simulation of the {pair.name} landscape failed; the first: {errors[0]}")
    return Landscape(pair, tuple(losses), first, second, values, fixed)


def save_landscape(path: str | os.PathLike, landscape: Landscape) -> None:
    """Write ``landscape`` to ``path`` (.npz) atomically: arrays ``first``, ``second``, ``values``, ``fixed``
    (the six parameters in :data:`~dpsi.parameters.NAMES` order) and the text ``meta`` (pair, level, losses)."""
    pair = landscape.pair
    meta = {"first": pair.first, "second": pair.second, "level": pair.level, "losses": list(landscape.losses)}
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, meta=json.dumps(meta), first=landscape.first, second=landscape.second,
                 values=landscape.values, fixed=landscape.fixed.as_array())


def load_landscape(path: str | os.PathLike) -> Landscape:
    """Read a landscape written by :func:`save_landscape`; errors name the file."""
    try:
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            return Landscape(Pair(meta["first"], meta["second"], int(meta["level"])), tuple(meta["losses"]),
                             data["first"], data["second"], data["values"], Parameters.from_array(data["fixed"]))
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"{path} is not a landscape file: {err}") from err


__all__ = ["Pair", "PAIRS", "pair_by_name", "axis", "Landscape", "mean_losses", "compute", "save_landscape",
           "load_landscape"]
