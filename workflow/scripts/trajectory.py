"""Trajectory stage: the planner trajectory resampled to 0.01 s steps, and the tip's start."""

from pathlib import Path

import numpy as np

from dpsi import prepare
from dpsi.pointclouds import atomic_output
from dpsi.provenance import recorded
from dpsi.rawdata import load_raw_dataset

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    datapoint = load_raw_dataset(Path(snakemake.input[0]).parent, only=[snakemake.wildcards.id]).datapoint(snakemake.wildcards.id)
    trajectory, start = prepare.trajectory_and_start(datapoint.trajectory)
    with atomic_output(snakemake.output[0]) as tmp, open(tmp, "wb") as f:
        np.savez(f, positions=trajectory.positions, yaw=trajectory.yaw, dt=trajectory.dt, start=start)
