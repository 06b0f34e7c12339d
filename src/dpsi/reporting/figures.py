"""Figures of identification runs and of simulated vs real outcomes (SPEC §7).

Every figure is written twice, as a PNG and a PDF, each atomically. Figures are built on the Agg
canvas without pyplot, so no GUI backend or global figure state is involved.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colors, ticker
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from dpsi.datapoint import Datapoint
from dpsi.heightmap import SIZE, heightmap_distance_mm
from dpsi.losses import VALIDATION_METRICS as METRICS
from dpsi.losses import simulated_heightmap
from dpsi.parameters import IDENTIFIED, LOWER, SCALE_FREE, UPPER
from dpsi.files import atomic_output, check_points


DPI = 150
"""Resolution of the PNG files (dots per inch)."""

MM_PER_M = 1000.0

TITLE_CHARS_PER_INCH = 8.5
"""Characters of a figure title per inch of figure width, beyond which the title is wrapped."""

METRIC_LABELS = {"pcd_cd": "PCD-CD (mm)", "prt_cd": "PRT-CD (mm)", "pcd_emd": "PCD-EMD (mm)",
                 "prt_emd": "PRT-EMD (mm)", "heightmap_mm": "height map (mm)"}
"""Axis label of each validation metric."""

PARAMETER_AXES = {"E": ("$E$ (kPa)", 1e-3), "nu": (r"$\nu$ (-)", 1.0), "rho": (r"$\rho$ (kg/m³)", 1.0),
                  "yield_stress": (r"$\sigma_y$ (kPa)", 1e-3), "mu_table": (r"$\mu_\mathrm{table}$ (-)", 1.0),
                  "mu_effector": (r"$\mu_\mathrm{effector}$ (-)", 1.0)}
"""Axis label and the factor from the SI value to the plotted unit, per parameter."""

RUN_KEYS = ("level", "seed", "iteration")
"""Columns that every table given to :func:`plot_runs` needs besides its column and colour keys."""


def new_figure(width: float, height: float, layout: str | None = "constrained") -> Figure:
    """An empty figure of ``width`` × ``height`` inches on the Agg canvas with matplotlib's ``layout``."""
    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save(fig: Figure, png_path: str | Path, pdf_path: str | Path) -> None:
    """Write ``fig`` to ``png_path`` (at :data:`DPI`) and ``pdf_path``, each atomically."""
    outputs = ((Path(png_path), "png"), (Path(pdf_path), "pdf"))
    for path, fmt in outputs:
        if path.suffix.lower() != f".{fmt}":
            raise ValueError(f"{path}: a {fmt.upper()} figure needs the suffix .{fmt}")
    for path, fmt in outputs:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, format=fmt, dpi=DPI)


def _check_runs(runs: pd.DataFrame, level: int, keys: tuple[str, ...]) -> pd.DataFrame:
    """The rows of ``level``, after checking the table has what :func:`plot_runs` needs (``keys``: its
    column and colour keys)."""
    if level not in IDENTIFIED:
        raise ValueError(f"unknown level {level}; levels are {sorted(IDENTIFIED)}")
    needed = [*RUN_KEYS, *keys, *(f"val_{m}" for m in METRICS), *IDENTIFIED[level]]
    missing = [c for c in dict.fromkeys(needed) if c not in runs.columns]
    if missing:
        raise ValueError(f"runs table lacks column(s) {missing}")
    if runs.empty:
        raise ValueError("runs table is empty: nothing to plot")
    rows = runs[runs["level"] == level]
    if rows.empty:
        raise ValueError(f"runs table has no rows of level {level}; it has levels {sorted(runs['level'].unique())}")
    return rows


def plot_runs(runs: pd.DataFrame, level: int, png_path: str | Path, pdf_path: str | Path, columns: str = "dataset",
              colours: str = "loss", title: str | None = None,
              truth: Mapping[str, Mapping[str, float]] | None = None) -> Figure:
    """Validation metrics (mm) and identified parameters of ``level`` over the iterations; returns the
    saved figure.

    ``runs`` holds the identification log columns plus level, seed and the keys ``columns`` and
    ``colours``. One figure column per value of ``columns`` (default the dataset); one row per validation
    metric then per identified parameter (y-limits = its range); each seed a thin dotted line, the mean
    over seeds a solid line, one colour per value of ``colours`` (default the loss). ``truth``: known
    parameter values (SI) per value of ``columns``, drawn as dashed black lines."""
    rows = _check_runs(runs, level, (columns, colours))
    panels, groups = list(pd.unique(rows[columns])), list(pd.unique(rows[colours]))
    quantities = [(f"val_{m}", METRIC_LABELS[m], 1.0) for m in METRICS]
    quantities += [(n, *PARAMETER_AXES[n]) for n in IDENTIFIED[level]]
    colour = {group: f"C{k}" for k, group in enumerate(groups)}

    fig = new_figure(2.0 + 3.0 * len(panels), 1.0 + 1.45 * len(quantities))
    axes = fig.subplots(len(quantities), len(panels), sharex=True, sharey="row", squeeze=False)
    for c, panel in enumerate(panels):
        axes[0, c].set_title(str(panel), fontsize="medium")
        axes[-1, c].set_xlabel("iteration")
        for group in groups:
            one = rows[(rows[columns] == panel) & (rows[colours] == group)]
            for r, (column, _, scale) in enumerate(quantities):
                by_seed = one.pivot_table(index="iteration", columns="seed", values=column, dropna=False) * scale
                _plot_seeds(axes[r, c], by_seed, colour[group])
        for r, (column, _, scale) in enumerate(quantities):
            if truth and column in truth.get(panel, {}):
                axes[r, c].axhline(truth[panel][column] * scale, color="black", linestyle="--", linewidth=1.0)
    first, last = rows["iteration"].min(), rows["iteration"].max()
    pad = 0.02 * (last - first) if last > first else 1.0
    axes[0, 0].set_xlim(first - pad, last + pad)
    for r, (column, label, scale) in enumerate(quantities):
        axes[r, 0].set_ylabel(label)
        if column in LOWER:
            axes[r, 0].set_ylim(LOWER[column] * scale, UPPER[column] * scale)
    for ax in axes.flat:
        ax.xaxis.set_major_locator(ticker.MaxNLocator(nbins=5, integer=True, steps=[1, 2, 2.5, 5, 10]))
        ax.yaxis.set_major_locator(ticker.MaxNLocator(nbins=4))
        ax.grid(alpha=0.3)
    handles = [Line2D([], [], color=colour[group], label=str(group)) for group in groups]
    handles += [Line2D([], [], color="grey", label="mean over seeds"),
                Line2D([], [], color="grey", linestyle=":", label="one seed")]
    if truth:
        handles.append(Line2D([], [], color="black", linestyle="--", label="truth"))
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 2 + len(panels)),
               frameon=False)
    fig.suptitle(textwrap.fill(title or f"Level {level}: validation metrics and identified parameters",
                               width=int(TITLE_CHARS_PER_INCH * fig.get_figwidth())))
    save(fig, png_path, pdf_path)
    return fig


def _plot_seeds(ax, by_seed: pd.DataFrame, colour: str) -> None:
    """Each seed (columns of ``by_seed``, indexed by iteration) dotted and their mean solid."""
    marker = "o" if len(by_seed) == 1 else None
    for seed in by_seed.columns:
        ax.plot(by_seed.index, by_seed[seed], color=colour, linestyle=":", linewidth=0.8, alpha=0.7,
                marker=marker, markersize=3)
    ax.plot(by_seed.index, by_seed.mean(axis=1, skipna=True), color=colour, linewidth=1.6,
            marker=marker, markersize=4)


def plot_heightmaps(datapoint: Datapoint, final_particles, png_path: str | Path, pdf_path: str | Path,
                    title: str = "") -> Figure:
    """Real vs simulated height map (mm above the table) and simulated − real (mm), with the
    height-map distance (mm) in the title. ``final_particles`` (n, 3) in m. Returns the saved figure."""
    real = np.asarray(datapoint.heightmap, dtype=float)
    sim = simulated_heightmap(check_points(final_particles, "final particles"), datapoint.heightmap_target())
    distance = heightmap_distance_mm(sim, real)
    real_mm, sim_mm = ((m - datapoint.table_z) * MM_PER_M for m in (real, sim))
    diff_mm = sim_mm - real_mm
    half = 0.5 * SIZE * MM_PER_M
    extent = (-half, half, -half, half)
    heights = colors.Normalize(min(real_mm.min(), sim_mm.min()), max(real_mm.max(), sim_mm.max(), 1e-3))
    largest = max(np.abs(diff_mm).max(), 1e-3)

    fig = new_figure(12.0, 4.2)
    axes = fig.subplots(1, 3)
    panels = ((real_mm, "real", "viridis", heights), (sim_mm, "simulated", "viridis", heights),
              (diff_mm, "simulated − real", "RdBu_r", colors.Normalize(-largest, largest)))
    for ax, (values, name, cmap, norm) in zip(axes, panels):
        image = ax.imshow(values.T, origin="lower", extent=extent, cmap=cmap, norm=norm)
        ax.set_title(name)
        ax.set_xlabel("x from map centre (mm)")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y from map centre (mm)")
    fig.colorbar(axes[1].images[0], ax=axes[:2], label="height above table (mm)", shrink=0.85)
    fig.colorbar(image, ax=axes[2], label="difference (mm)", shrink=0.85)
    detail = f"height-map distance {distance:.1f} mm"
    fig.suptitle(f"{title}\n{detail}" if title else detail)
    save(fig, png_path, pdf_path)
    return fig


def plot_particles(datapoint: Datapoint, final_particles, png_path: str | Path, pdf_path: str | Path,
                   title: str = "") -> Figure:
    """Particles before, simulated after and the PRT target, as 3D scatter plots in mm with equal
    axis scales, shared limits and the same view. ``final_particles`` (n, 3) in m. Returns the saved
    figure."""
    panels = (("before", check_points(datapoint.particles, "datapoint particles")),
              ("simulated after", check_points(final_particles, "final particles")),
              ("target (PRT)", check_points(datapoint.prt_target, "PRT target")))
    panels = [(name, points * MM_PER_M) for name, points in panels]
    everything = np.concatenate([points for _, points in panels])
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    pad = 0.05 * max(np.ptp(everything, axis=0).max(), 1.0)
    lo, hi = lo - pad, hi + pad
    heights = colors.Normalize(lo[2], hi[2])

    fig = new_figure(13.0, 4.6, layout=None)  # constrained layout does not handle 3D axes
    fig.subplots_adjust(left=0.0, right=0.97, bottom=0.0, top=0.95, wspace=0.08)
    for k, (name, points) in enumerate(panels):
        ax = fig.add_subplot(1, 3, k + 1, projection="3d")
        ax.scatter(*points.T, c=points[:, 2], cmap="viridis", norm=heights, s=2, depthshade=False)
        ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]),
               xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
        ax.set_box_aspect(hi - lo, zoom=0.9)
        ax.view_init(elev=35, azim=-60)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(ticker.MaxNLocator(nbins=4))
        ax.set_title(f"{name} (n = {len(points)})", y=0.93)
    fig.suptitle(title)
    save(fig, png_path, pdf_path)
    return fig


def plot_recovery(table: pd.DataFrame, png_path: str | Path, pdf_path: str | Path) -> None:
    """Identifiability ladder figure: relative error (%) of each identified parameter, one panel per
    (level, dataset) row and rung column, bars per loss (median over seeds) and a dot per run. ``table`` has
    the columns of :data:`dpsi.identifiability.COLUMNS`."""
    missing = [c for c in ("rung", "level", "dataset", "loss", "parameter", "rel_error") if c not in table.columns]
    if missing or table.empty:
        raise ValueError(f"ladder table is empty or lacks column(s) {missing}: nothing to plot")
    rows = list(dict.fromkeys(zip(table["level"], table["dataset"])))
    rungs = sorted(set(table["rung"]))
    losses = list(dict.fromkeys(table["loss"]))
    fig = new_figure(4.2 * len(rungs), 3.4 * len(rows))
    axes = np.array(fig.subplots(len(rows), len(rungs), sharey=True, squeeze=False))
    width = 0.8 / len(losses)
    for (level, dataset), row_axes in zip(rows, axes):
        for ax, rung in zip(row_axes, rungs):
            panel = table[(table["level"] == level) & (table["dataset"] == dataset) & (table["rung"] == rung)]
            if panel.empty:
                ax.set_visible(False)
                continue
            ax.set_title(f"level {level}, {dataset}, {rung}", fontsize=9)
            names = [n for n in (*IDENTIFIED[level], *SCALE_FREE) if n in set(panel["parameter"])]
            for k, loss in enumerate(losses):
                mine = panel[panel["loss"] == loss]
                x = np.arange(len(names)) + (k - (len(losses) - 1) / 2) * width
                errors = [100 * mine.loc[mine["parameter"] == n, "rel_error"] for n in names]
                ax.bar(x, [e.median() if len(e) else np.nan for e in errors], width, label=loss, color=f"C{k}")
                for xi, e in zip(x, errors):
                    ax.plot(np.full(len(e), xi), e, "k.", markersize=3)
            ax.set_xticks(np.arange(len(names)), [PARAMETER_AXES[n][0].split(" (")[0] if n in PARAMETER_AXES else n
                                                  for n in names], fontsize=7)
            ax.set_yscale("symlog", linthresh=10)
            ax.axhline(10, color="grey", lw=0.8, ls="--")
            ax.set_ylabel("relative error (%)")
    handles = {label: h for ax in axes.flat for h, label in zip(*ax.get_legend_handles_labels())}
    fig.legend(handles.values(), handles.keys(), fontsize=7, loc="outside lower center", ncols=len(handles))
    fig.suptitle("Identifiability ladder: recovery error per parameter (dashed: 10 %)")
    save(fig, png_path, pdf_path)


def plot_intervals(table: pd.DataFrame, png_path: str | Path, pdf_path: str | Path, title: str) -> None:
    """What each run's data determine: one panel per parameter and ratio (not the principal directions, whose
    names differ by run), one line per run with its estimate (dot) and interval (bar: solid where determined,
    dotted grey where it reaches a bound of the range, i.e. not determined) on a log axis, and the truth (black
    cross) where known. ``table`` has the columns of uncertainty.csv."""
    missing = [c for c in ("level", "loss", "dataset", "seed", "quantity", "estimate", "low", "high", "determined",
                           "truth") if c not in table.columns]
    shown = table[~table["quantity"].str.contains("^", regex=False)] if not missing else table
    if missing or shown.empty:
        raise ValueError(f"uncertainty table is empty or lacks column(s) {missing}: nothing to plot")
    names = list(dict.fromkeys(shown["quantity"]))
    run_keys = [k for k in ("rung", "level", "loss", "dataset", "seed") if k in shown.columns]
    runs = list(dict.fromkeys(shown[run_keys].itertuples(index=False, name=None)))
    fig = new_figure(1.0 + 2.4 * len(names), 1.4 + 0.28 * len(runs))
    axes = fig.subplots(1, len(names), sharey=True, squeeze=False)[0]
    for ax, name in zip(axes, names):
        mine = shown[shown["quantity"] == name]
        for y, run in enumerate(runs):
            row = mine[np.logical_and.reduce([mine[k] == v for k, v in zip(run_keys, run)])]
            if row.empty:
                continue
            r = row.iloc[0]
            determined = bool(r["determined"])
            ax.plot([r["low"], r["high"]], [y, y], color="C0" if determined else "grey",
                    linestyle="-" if determined else ":", linewidth=2.0 if determined else 1.2)
            ax.plot(r["estimate"], y, "o", color="C0" if determined else "grey", markersize=4)
            if pd.notna(r["truth"]):
                ax.plot(r["truth"], y, "x", color="black", markersize=6)
        ax.set_xscale("log")
        ax.set_title(PARAMETER_AXES[name][0].split(" (")[0] if name in PARAMETER_AXES else name, fontsize=9)
        ax.grid(alpha=0.3, which="both", axis="x")
    axes[0].set_yticks(range(len(runs)), [" ".join(str(v) for v in run) for run in runs], fontsize=7)
    axes[0].invert_yaxis()
    handles = [Line2D([], [], color="C0", marker="o", label="determined"),
               Line2D([], [], color="grey", linestyle=":", marker="o", label="not determined (reaches a bound)"),
               Line2D([], [], color="black", marker="x", linestyle="", label="truth")]
    fig.legend(handles=handles, loc="outside lower center", ncols=3, frameon=False, fontsize=8)
    fig.suptitle(textwrap.fill(title, width=int(TITLE_CHARS_PER_INCH * fig.get_figwidth())))
    save(fig, png_path, pdf_path)


__all__ = ["DPI", "METRIC_LABELS", "PARAMETER_AXES", "new_figure", "save", "plot_runs", "plot_heightmaps",
           "plot_particles", "plot_recovery", "plot_intervals"]
