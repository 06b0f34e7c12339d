"""Computing a loss landscape (:class:`dpsi.landscapes.Landscape`) by simulation. Every loss is a function of
the final particle positions, so one forward simulation per grid point and datapoint serves all of them. All
four other parameters come from the fixed values, at level 1 too (the twin's clay has the frictions that
level-1 identification holds fixed, so with its truth the two agree).

A grid point at which a datapoint's simulation fails (:class:`~dpsi.simulation.SimulationError`, e.g. an
instability) is NaN for every loss; if every grid point fails, the landscape is refused with the first
error, since that points to a problem of the setup (capacity, box) rather than of the parameters.
"""

from __future__ import annotations

import logging
from typing import Sequence, TextIO

import numpy as np

from dpsi.datapoint import Datapoint
from dpsi.identification import scene, targets
from dpsi.landscapes import Landscape, Pair, grid_axes
from dpsi.losses import loss_by_name
from dpsi.parameters import Parameters
from dpsi.progress import Progress
from dpsi.simulation import SimulationError, Simulator

log = logging.getLogger(__name__)


def mean_losses(simulator: Simulator, datapoints: Sequence[Datapoint], params: Parameters,
                losses: Sequence[str]) -> np.ndarray:
    """Each loss (mm) averaged over ``datapoints`` simulated with ``params``, shape (len(losses),);
    raises :class:`SimulationError` if a simulation fails."""
    functions = [loss_by_name(name) for name in losses]
    per_datapoint = []
    for dp in datapoints:
        final = simulator.forward(scene(dp), params, keep_substeps=False)
        per_datapoint.append([f(final, targets(dp))[0] for f in functions])
    return np.mean(per_datapoint, axis=0)


def compute(simulator: Simulator, datapoints: Sequence[Datapoint], pair: Pair, fixed: Parameters,
            resolution: int, losses: Sequence[str], progress: TextIO | None = None) -> Landscape:
    """The landscape of ``losses`` over ``pair`` on ``datapoints``: :func:`on_grid` of the pair's axes
    (:func:`dpsi.landscapes.grid_axes`: ``resolution`` values over each full range, or around ``fixed``)."""
    return on_grid(simulator, datapoints, pair, fixed, *grid_axes(pair, fixed, resolution), losses, progress)


def on_grid(simulator: Simulator, datapoints: Sequence[Datapoint], pair: Pair, fixed: Parameters,
            first: Sequence[float], second: Sequence[float], losses: Sequence[str],
            progress: TextIO | None = None) -> Landscape:
    """The landscape of ``losses`` on ``datapoints`` at every pair of ``pair.first`` in ``first`` and
    ``pair.second`` in ``second`` (SI), the other parameters at ``fixed`` (see the module doc for failures);
    progress per grid point on ``progress`` (default stderr)."""
    if not datapoints:
        raise ValueError("a landscape needs at least one datapoint")
    for name in losses:
        loss_by_name(name)
    first, second = np.asarray(first, dtype=float), np.asarray(second, dtype=float)
    values = np.full((len(losses), len(first), len(second)), np.nan)
    errors = []
    bar = Progress(values[0].size, f"landscape {pair.name}", progress)
    for i, x in enumerate(first):
        for j, y in enumerate(second):
            params = fixed.replace(**{pair.first: x, pair.second: y})
            where = f"{pair.first}={x:g}, {pair.second}={y:g}"
            try:
                values[:, i, j] = mean_losses(simulator, datapoints, params, losses)
                status = ", ".join(f"{n} {v:.1f} mm" for n, v in zip(losses, values[:, i, j]))
            except SimulationError as err:
                errors.append(err)
                log.warning("%s: simulation failed, cell left NaN: %s", where, err)
                status = "simulation failed"
            bar.update(i * len(second) + j + 1, f"{where}: {status}")
    bar.close()
    if len(errors) == values[0].size:
        raise SimulationError(f"every simulation of the {pair.name} landscape failed; the first: {errors[0]}")
    return Landscape(pair, tuple(losses), first, second, values, fixed)


__all__ = ["mean_losses", "compute", "on_grid"]
