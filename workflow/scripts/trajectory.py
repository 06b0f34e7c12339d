"""Trajectory stage: the planner trajectory resampled to 0.01 s steps, and the tip's start."""

from dpsi import prepare
from dpsi.provenance import recorded
from dpsi.rawdata import trajectory_file

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    path = trajectory_file(snakemake.params.raw, snakemake.wildcards.id, snakemake.params.row["motion"])
    trajectory, start = prepare.trajectory_and_start(path)
    prepare.save_trajectory(snakemake.output[0], trajectory, start)
