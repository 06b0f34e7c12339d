"""Heat maps of loss landscapes. The paper's (SPEC §7.1): one figure per parameter pair, one row per loss,
one column per dataset, each map centralised to zero mean so that maps of different losses and datasets
share a reading: blue below the map's mean, red above. The identifiability ladder's: one column per rung,
each map minus its loss at the truth: blue fits the data better than the truth."""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from matplotlib import colormaps
from matplotlib.ticker import NullLocator

from dpsi.landscapes import Landscape, fixed_cell
from dpsi.parameters import NAMES
from dpsi.reporting.figures import PARAMETER_AXES, new_figure, save

LOSS_LABELS = {"pcd_cd": "PCD-CD", "prt_cd": "PRT-CD", "pcd_emd": "PCD-EMD", "prt_emd": "PRT-EMD",
               "heightmap": "height map", "neg_heightmap": "negated height map",
               "heightmap_interior": "interior height map"}
"""Display name of each training loss."""

COLOUR_MAP = "RdBu_r"
"""Diverging colour map: blue for losses below a map's mean, red above; NaN cells (failed simulations) grey."""


def centred(values: np.ndarray) -> np.ndarray:
    """``values`` minus their mean over the finite cells (same unit); NaN cells stay NaN."""
    values = np.asarray(values, dtype=float)
    finite = np.isfinite(values)
    return values - values[finite].mean() if finite.any() else values.copy()


def _check(columns: Sequence[tuple[str, Landscape]]) -> Landscape:
    """The first landscape, after checking that all of ``columns`` share its pair, losses and axes."""
    if not columns:
        raise ValueError("no landscapes to plot")
    first = columns[0][1]
    for dataset, landscape in columns:
        same_axes = np.array_equal(landscape.first, first.first) and np.array_equal(landscape.second, first.second)
        if landscape.pair != first.pair or landscape.losses != first.losses or not same_axes:
            raise ValueError(f"landscape of dataset {dataset!r} differs from that of {columns[0][0]!r} in its pair, "
                             "losses or axes; one figure shows one pair with the same losses and grid")
    return first


def _symbol_and_unit(name: str) -> tuple[str, str]:
    """Parameter ``name``'s symbol and plotted unit (``""`` if dimensionless), from its axis label."""
    symbol, unit = PARAMETER_AXES[name][0][:-1].rsplit(" (", 1)
    return symbol, "" if unit == "-" else unit


def _fixed_text(landscape: Landscape) -> str:
    """The values of the parameters not on the axes in the plotted units, e.g. ``"$\\rho$ = 1330 kg/m³"``,
    joined by commas."""
    parts = []
    for name in NAMES:
        if name not in landscape.pair[:2]:
            symbol, unit = _symbol_and_unit(name)
            parts.append(f"{symbol} = {getattr(landscape.fixed, name) * PARAMETER_AXES[name][1]:.4g} {unit}".strip())
    return ", ".join(parts)


def _cell_edges(values: np.ndarray, log: bool = False) -> np.ndarray:
    """Edges of the cells around evenly or unevenly spaced grid ``values`` (k,): the midpoints between
    neighbours (geometric if ``log``), and the first and last value themselves, so that the map spans
    exactly the axis range."""
    middle = np.sqrt(values[1:] * values[:-1]) if log else (values[1:] + values[:-1]) / 2
    return np.concatenate([values[:1], middle, values[-1:]])


def _heat_map(fig, ax, landscape: Landscape, k: int, truth: bool = False) -> None:
    """Loss ``k`` of ``landscape`` on a symmetric colour scale, with the fixed parameters (star) and the grid
    minimum (cross) marked. Centralised to zero mean; or, if ``truth`` (the fixed parameters are the truth,
    held on the grid), minus the loss at the truth, on logarithmic axes, with the line where it equals it."""
    (x_label, x_scale), (y_label, y_scale) = (PARAMETER_AXES[n] for n in landscape.pair[:2])
    x_edges, y_edges = _cell_edges(landscape.first, truth) * x_scale, _cell_edges(landscape.second, truth) * y_scale
    if truth:
        values = landscape.values[k] - landscape.values[k][fixed_cell(landscape)]
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis, grid in ((ax.xaxis, landscape.first * x_scale), (ax.yaxis, landscape.second * y_scale)):
            axis.set_ticks(grid, [f"{v:.3g}" for v in grid])
            axis.set_minor_locator(NullLocator())
    else:
        values = centred(landscape.values[k])
    reach = np.nanmax(np.abs(values)) if np.isfinite(values).any() else 0.0
    reach = reach if reach > 0 else 1.0
    cmap = colormaps[COLOUR_MAP].with_extremes(bad="0.6")
    mesh = ax.pcolormesh(x_edges, y_edges, values.T, cmap=cmap, vmin=-reach, vmax=reach)
    reference = "at the truth" if truth else "mean"
    fig.colorbar(mesh, ax=ax, label=f"{LOSS_LABELS[landscape.losses[k]]} − {reference} (mm)")
    pair = landscape.pair
    if truth and np.nanmin(values) < 0:
        ax.contour(landscape.first * x_scale, landscape.second * y_scale, values.T, levels=[0.0], colors="k",
                   linewidths=1.0, linestyles="--")
    ax.plot(getattr(landscape.fixed, pair.first) * x_scale, getattr(landscape.fixed, pair.second) * y_scale,
            marker="*", markersize=13, color="k", markeredgecolor="w", linestyle="none",
            label="truth" if truth else "fixed θ", clip_on=False, zorder=3)
    if np.isfinite(values).any():
        i, j = np.unravel_index(np.nanargmin(values), values.shape)
        ax.plot(landscape.first[i] * x_scale, landscape.second[j] * y_scale, marker="x", markersize=9,
                markeredgewidth=2, color="k", linestyle="none", label="grid minimum", clip_on=False, zorder=3)
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)


def _plot(columns: Sequence[tuple[str, Landscape]], png_path: str | Path, pdf_path: str | Path, truth: bool,
          title: Callable[[Landscape], str]) -> None:
    """Heat maps of ``columns`` ((label, landscape) per column, the losses in rows; see :func:`_heat_map` for
    ``truth``) under ``title`` (of the first landscape) + the other parameters' values, written to
    ``png_path`` and ``pdf_path``."""
    first = _check(columns)
    n_rows, n_cols = len(first.losses), len(columns)
    fig = new_figure(max(4.2 * n_cols, 6.5), 3.3 * n_rows + 0.8)
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    for col, (label, landscape) in enumerate(columns):
        for k, loss in enumerate(landscape.losses):
            _heat_map(fig, axes[k, col], landscape, k, truth)
            axes[k, col].set_title(f"{LOSS_LABELS[loss]}, {label}", fontsize="medium")
    axes[0, 0].legend(loc="lower left", fontsize="small", framealpha=0.8)
    fig.suptitle(f"{title(first)}\nother parameters: {_fixed_text(first)}", fontsize="medium")
    save(fig, png_path, pdf_path)


def _symbols(landscape: Landscape) -> str:
    """The symbols of the landscape's two parameters, e.g. ``"$E$, $\\nu$"``."""
    return ", ".join(_symbol_and_unit(name)[0] for name in landscape.pair[:2])


def plot_landscapes(columns: Sequence[tuple[str, Landscape]], png_path: str | Path, pdf_path: str | Path) -> None:
    """One figure of the landscapes of one pair: ``columns`` is (dataset name, landscape) per column, rows
    are the losses, each map centralised; written to ``png_path`` and ``pdf_path``."""
    _plot(columns, png_path, pdf_path, False, lambda first: f"Loss landscapes over ({_symbols(first)}) on "
                                                            f"level-{first.pair.level} datasets, centralised to zero mean")


def plot_truth_landscapes(columns: Sequence[tuple[str, Landscape]], png_path: str | Path,
                          pdf_path: str | Path) -> None:
    """The identifiability ladder's landscapes around the truth (:mod:`dpsi.identifiability_landscape`):
    ``columns`` is (rung, landscape) per column, rows are the losses, each map minus its loss at the truth
    (blue cells fit the data better than the truth; the dashed line is where a cell fits them as well);
    written to ``png_path`` and ``pdf_path``."""
    _plot(columns, png_path, pdf_path, True, lambda first: f"Losses over ({_symbols(first)}) around the truth, "
                                                           "minus the loss at the truth: blue fits the data better "
                                                           "than the truth")


__all__ = ["LOSS_LABELS", "COLOUR_MAP", "centred", "plot_landscapes", "plot_truth_landscapes"]
