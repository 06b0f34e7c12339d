"""The computation cost table (SPEC §7.6) from the records of :func:`dpsi.bench.measure_simulation`.

``cost.csv`` columns (an interface other tools read): motion, density (particles/m³), particles, steps,
substeps, taichi_cache (off / warm / cold: how Taichi's offline kernel cache served the measuring
process), base_mem_mib, first_forward_s, forward_s, forward_mem_mib, first_backward_s, backward_s,
backward_mem_mib, iterations, total_min, total_label.

Times in s. Memory is the measuring process's peak resident memory in MiB: before the simulator exists
(``base_mem_mib``: Python, Taichi, the libraries that fill the lump), after the forward passes (before any
backward pass) and after the backward passes. ``total_min``: the time of ``iterations`` forward + backward
iterations in minutes; ``total_label``: "measured" or "extrapolated from N iterations".
"""

from __future__ import annotations

import pandas as pd

COLUMNS = ("motion", "density", "particles", "steps", "substeps", "taichi_cache", "base_mem_mib", "first_forward_s",
           "forward_s", "forward_mem_mib", "first_backward_s", "backward_s", "backward_mem_mib", "iterations",
           "total_min", "total_label")
MEASURED_LABEL = "measured"


def iterations_total(iteration_s: list[float], iterations: int) -> tuple[float, str]:
    """Time (s) of ``iterations`` iterations from the measured times ``iteration_s`` (s each) and its label:
    the sum of the first ``iterations`` times, "measured", when that many were timed; otherwise their mean
    times ``iterations``, "extrapolated from N iterations"."""
    if not iteration_s:
        raise ValueError("no measured iteration to report a total from")
    if len(iteration_s) >= iterations:
        return float(sum(iteration_s[:iterations])), MEASURED_LABEL
    n = len(iteration_s)
    return iterations * sum(iteration_s) / n, f"extrapolated from {n} iteration{'s' if n > 1 else ''}"


def cost_row(record: dict, iterations: int) -> dict:
    """One row of the table from one measurement record, with the total for ``iterations`` iterations."""
    total_s, label = iterations_total(record["iteration_s"], iterations)
    return dict(motion=record["motion"], density=record["density"], particles=record["particles"],
                steps=record["steps"], substeps=record["substeps"], taichi_cache=record["taichi_cache"],
                base_mem_mib=record["base_peak_rss_mb"], first_forward_s=record["first_forward_s"],
                forward_s=record["forward_s"], forward_mem_mib=record["forward_peak_rss_mb"],
                first_backward_s=record["first_backward_s"], backward_s=record["backward_s"],
                backward_mem_mib=record["peak_rss_mb"], iterations=iterations, total_min=total_s / 60.0,
                total_label=label)


def cost_table(records: list[dict], iterations: int) -> pd.DataFrame:
    """The cost table: one row per record (one per motion and density), in the order given, with the
    total for ``iterations`` forward + backward iterations."""
    return pd.DataFrame([cost_row(r, iterations) for r in records], columns=list(COLUMNS))
