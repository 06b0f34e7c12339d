"""Landscapes of the identifiability ladder: the ladder's losses over (E, σ_y) around the truth on a rung's
training datapoints, and the region of parameters the data cannot tell from the truth.

On the twin the truth θ* is known, so a landscape answers what no identification run can: which parameters
the data determine. The grid holds E and σ_y at :data:`~dpsi.landscapes.SCAN_FACTORS` times the truth (within their ranges), ν, ρ
and the frictions at the truth. A cell whose loss is no higher than the loss at θ* fits the data at least
as well as the truth does, so no optimiser has a reason to prefer θ* to it. How far those cells reach along
a parameter is how well the data determine it: at R0 the truth alone (every loss is zero there and only
there), on reconstructed data a band wherever the motion leaves a parameter's effect below the data's
errors. Units: mm for losses, SI for parameters, multiples of the truth for the reach.
"""

from __future__ import annotations

from typing import Sequence, TextIO

import numpy as np
import pandas as pd

from dpsi.datapoint import Datapoint
from dpsi.identifiability import level_truth
from dpsi.landscape_compute import compute
from dpsi.landscapes import AROUND_FIXED, SCAN_FACTORS, Landscape, fixed_cell
from dpsi.parameters import Parameters
from dpsi.simulation import Simulator

PAIR = AROUND_FIXED[0]
"""The parameters on the axes, (E, σ_y) at level 1: the two whose recovery the ladder's targets name."""

COLUMNS = ("loss", "parameter", "truth", "argmin", "loss_at_truth_mm", "loss_min_mm", "as_good_from",
           "as_good_to", "as_good_cells", "cells")
"""Columns of :func:`as_good_as_truth`."""


def truth_landscape(simulator: Simulator, datapoints: Sequence[Datapoint], truth: Parameters,
                    losses: Sequence[str], progress: TextIO | None = None) -> Landscape:
    """``losses`` (mm, mean over ``datapoints``) over :data:`PAIR` around ``truth``, the other parameters at
    the truth as level 1 holds them (frictions fixed)."""
    return compute(simulator, datapoints, PAIR, level_truth(truth, PAIR.level), len(SCAN_FACTORS), losses, progress)


def as_good_as_truth(landscape: Landscape) -> pd.DataFrame:
    """Per loss, for each axis parameter and their ratio (second / first, e.g. the yield strain σ_y / E):
    the truth and the grid minimum (SI), the loss at the truth and the lowest (mm), and how far the cells no
    worse than the truth reach (``as_good_from`` … ``as_good_to``, multiples of the truth; 1 … 1 when only
    the truth's own value fits that well, up to the grid's resolution), with the number of those cells among
    the finite ones."""
    i0, j0 = fixed_cell(landscape)
    pair, first, second = landscape.pair, landscape.first[:, None], landscape.second[None, :]
    shape = landscape.values.shape[1:]
    grids = {pair.first: np.broadcast_to(first, shape), pair.second: np.broadcast_to(second, shape),
             f"{pair.second}/{pair.first}": second / first}
    rows = []
    for k, loss in enumerate(landscape.losses):
        values = landscape.values[k]
        at_truth = values[i0, j0]
        if not np.isfinite(at_truth):
            raise ValueError(f"the {loss} landscape has no value at the truth (its simulation failed)")
        good = np.isfinite(values) & (values <= at_truth)
        best = np.unravel_index(np.nanargmin(values), values.shape)
        for name, grid in grids.items():
            true = grid[i0, j0]
            reach = grid[good] / true
            rows.append({"loss": loss, "parameter": name, "truth": true, "argmin": grid[best],
                         "loss_at_truth_mm": at_truth, "loss_min_mm": float(np.nanmin(values)),
                         "as_good_from": reach.min(), "as_good_to": reach.max(),
                         "as_good_cells": int(good.sum()), "cells": int(np.isfinite(values).sum())})
    return pd.DataFrame(rows, columns=list(COLUMNS))


__all__ = ["PAIR", "COLUMNS", "truth_landscape", "as_good_as_truth"]
