"""Assemble the prepared datapoint that identification reads."""

from dpsi import prepare
from dpsi.datapoint import save_datapoint
from dpsi.pointclouds import read_points
from dpsi.provenance import recorded
from dpsi.rawdata import read_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    dataset = read_checked(snakemake.input.checked)
    datapoint = dataset.datapoints[0]
    trajectory, start = prepare.load_trajectory(snakemake.input.trajectory)
    save_datapoint(snakemake.output[0], prepare.assemble(
        datapoint.id, datapoint.motion, dataset.effectors[datapoint.effector].effector(),
        read_points(snakemake.input.particles), snakemake.params.density, trajectory, start,
        prepare.load_targets(snakemake.input.targets)))
