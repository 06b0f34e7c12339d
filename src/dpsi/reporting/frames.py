"""Frames along an out-of-distribution trajectory: the real captures (before and after) above the
object simulated with each set of parameters, seen from the side (SPEC §7.3).

Only the start and the end of a motion are captured, so the real row has frames in the first and last
columns; the simulated rows show every frame. Each panel projects the particles onto the x–z plane
(mm), coloured by y, with the effector tip and its path so far.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib import colors

from dpsi.datapoint import Datapoint
from dpsi.reporting.figures import MM_PER_M, new_figure, save


FRAMES = 5
"""Frames per trajectory, evenly spaced in time from the start to the end."""


def frame_steps(n_steps: int, count: int = FRAMES) -> np.ndarray:
    """Steps (0 … n_steps, increasing, distinct) at which frames are shown."""
    if n_steps < 1 or count < 2:
        raise ValueError(f"need at least one step and two frames, got {n_steps} steps and {count} frames")
    return np.unique(np.linspace(0, n_steps, min(count, n_steps + 1)).round().astype(int))


def plot_frames(datapoint: Datapoint, simulated: Mapping[str, np.ndarray], steps, png_path: str | Path,
                pdf_path: str | Path, title: str = "") -> None:
    """One row per entry of ``simulated`` (label → positions (len(steps), n, 3) in m at ``steps``)
    below the real before/after row; one column per step."""
    steps = np.asarray(steps, dtype=int)
    for label, frames in simulated.items():
        if np.shape(frames) != (len(steps), len(datapoint.particles), 3):
            raise ValueError(f"frames of {label!r} have shape {np.shape(frames)}, expected "
                             f"{(len(steps), len(datapoint.particles), 3)}")
        if not np.isfinite(frames).all():
            raise ValueError(f"frames of {label!r} contain NaN or inf")
    real = {0: datapoint.particles, len(steps) - 1: datapoint.prt_target}
    rows = [("real", real)] + [(label, dict(enumerate(frames))) for label, frames in simulated.items()]
    tips = (datapoint.start + datapoint.trajectory.positions) * MM_PER_M
    everything = np.concatenate([p for _, frames in rows for p in frames.values()]) * MM_PER_M
    lo, hi = everything.min(axis=0) - 5.0, everything.max(axis=0) + 5.0
    hi[2] = max(hi[2], tips[:, 2].max() + 2.0)
    depth = colors.Normalize(lo[1], hi[1])

    floor = datapoint.table_z * MM_PER_M - 2.0
    panel = 2.6  # inches per panel width; the height follows the data's aspect
    aspect = (hi[2] - floor) / (hi[0] - lo[0])
    fig = new_figure(panel * len(steps) + 1.0, (panel * aspect + 0.55) * len(rows) + 0.7)
    axes = fig.subplots(len(rows), len(steps), sharex=True, sharey=True, squeeze=False)
    for r, (label, frames) in enumerate(rows):
        for c, step in enumerate(steps):
            ax = axes[r, c]
            if c in frames:
                points = frames[c] * MM_PER_M
                ax.scatter(points[:, 0], points[:, 2], c=points[:, 1], cmap="viridis", norm=depth, s=3,
                           linewidths=0)
            else:
                ax.text(0.5, 0.5, "not captured", transform=ax.transAxes, ha="center", va="center",
                        color="grey")
            ax.plot(tips[: step + 1, 0], tips[: step + 1, 2], color="tab:red", linewidth=0.8)
            ax.plot(*tips[step, [0, 2]], marker="v", color="tab:red", markersize=5)
            ax.axhline(datapoint.table_z * MM_PER_M, color="black", linewidth=0.6)
            ax.set(xlim=(lo[0], hi[0]), ylim=(floor, hi[2]), aspect="equal")
            if r == 0:
                ax.set_title(f"step {step} ({step * datapoint.trajectory.dt:.2f} s)", fontsize=9)
            if r == len(rows) - 1:
                ax.set_xlabel("x (mm)")
        axes[r, 0].set_ylabel(f"{label}\nz (mm)")
    fig.colorbar(axes[1, 0].collections[0], ax=axes, label="y (mm)", shrink=0.6)
    fig.suptitle(title or f"{datapoint.id}: real vs simulated frames (tip ▼)")
    save(fig, png_path, pdf_path)


__all__ = ["FRAMES", "frame_steps", "plot_frames"]
