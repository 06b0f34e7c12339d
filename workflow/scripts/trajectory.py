"""Trajectory stage: the planner trajectory resampled to 0.01 s steps, and the tip's start."""

from dpsi import prepare
from dpsi.provenance import recorded
from dpsi.rawdata import read_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    datapoint = read_checked(snakemake.input.checked).datapoints[0]
    trajectory, start = prepare.trajectory_and_start(datapoint.trajectory)
    prepare.save_trajectory(snakemake.output[0], trajectory, start)
