"""The planning table and figure (SPEC §7.8, the paper's appendix B).

``planning.csv`` columns: action (0 is the start state), motion (``none`` for the empty action), start_x_mm
and start_y_mm (the tip's start from the height-map centre; empty for the start state and empty actions),
heightmap_mm (distance to the target after the action) and skipped (candidates the simulator rejected).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from matplotlib import colors

from dpsi.heightmap import SIZE
from dpsi.motions import get_motion
from dpsi.reporting.figures import MM_PER_M, new_figure, save

if TYPE_CHECKING:  # importing dpsi.planning at run time would load the simulator
    from dpsi.planning import Plan

START_LABEL = "start"
"""Motion label of the row and panel of the state before the first action."""

PANELS_PER_ROW = 5


def planning_table(record: dict) -> pd.DataFrame:
    """One row for the start state and one per action of a plan record (:func:`dpsi.planning.plan_record`)."""
    centre = np.asarray(record["centre_xy"], dtype=float)
    rows = [{"action": 0, "motion": START_LABEL, "start_x_mm": math.nan, "start_y_mm": math.nan,
             "heightmap_mm": record["initial_distance_mm"], "skipped": 0}]
    for k, action in enumerate(record["actions"], start=1):
        x, y = ((np.asarray(action["start"][:2]) - centre) * MM_PER_M if action["start"] else (math.nan,) * 2)
        rows.append({"action": k, "motion": action["motion"], "start_x_mm": x, "start_y_mm": y,
                     "heightmap_mm": action["distance_mm"], "skipped": len(action["skipped"])})
    return pd.DataFrame(rows)


def plot_plan(plan: Plan, png_path: str | Path, pdf_path: str | Path, title: str = "") -> None:
    """The target height map, then the height map (mm above the table) of the start and after every action,
    each titled with its distance (mm) to the target; the tip's start is a dot and its sideways travel an
    arrow, in mm from the height-map centre."""
    floor = plan.target.floor
    maps = [plan.target.heights, plan.initial_heightmap, *(s.heightmap for s in plan.steps)]
    maps_mm = [(m - floor) * MM_PER_M for m in maps]
    titles = ["target", f"{START_LABEL}\n{plan.initial_distance_mm:.0f} mm"] + [
        f"{k}: {s.action.label}\n{s.distance_mm:.0f} mm" for k, s in enumerate(plan.steps, start=1)]
    heights = colors.Normalize(min(m.min() for m in maps_mm), max(max(m.max() for m in maps_mm), 1e-3))
    half = 0.5 * SIZE * MM_PER_M
    columns = min(PANELS_PER_ROW, len(maps))
    rows = math.ceil(len(maps) / columns)

    fig = new_figure(2.6 * columns + 1.0, 2.8 * rows + 0.6)
    axes = fig.subplots(rows, columns, squeeze=False).ravel()
    for ax, values, name in zip(axes, maps_mm, titles):
        ax.imshow(values.T, origin="lower", extent=(-half, half, -half, half), cmap="viridis", norm=heights)
        ax.set_title(name, fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x from map centre (mm)", fontsize=8)
    for ax, step in zip(axes[2:], plan.steps):
        _draw_action(ax, step.action, plan.target.centre_xy)
    for ax in axes[len(maps):]:
        ax.set_axis_off()
    for ax in axes[::columns]:
        ax.set_ylabel("y from map centre (mm)", fontsize=8)
    fig.colorbar(axes[0].images[0], ax=axes.tolist(), label="height above table (mm)", shrink=0.8)
    detail = f"height-map distance {plan.initial_distance_mm:.0f} mm → {plan.final_distance_mm:.0f} mm"
    fig.suptitle(f"{title}\n{detail}" if title else detail)
    save(fig, png_path, pdf_path)


def _draw_action(ax, action, centre_xy) -> None:
    """Mark an action's tip start (dot) and the motion's sideways travel (arrow) on a panel in mm."""
    if action.motion is None:
        return
    start = (np.asarray(action.start[:2]) - centre_xy) * MM_PER_M
    travel = get_motion(action.motion).end_offset()[0][:2] * MM_PER_M
    ax.plot(*start, "o", color="red", markersize=4)
    if np.any(travel):
        ax.annotate("", xy=start + travel, xytext=start, arrowprops={"arrowstyle": "->", "color": "red", "lw": 1.5})


__all__ = ["START_LABEL", "planning_table", "plot_plan"]
