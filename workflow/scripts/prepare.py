"""Assemble the prepared datapoint that identification reads."""

from dpsi import prepare
from dpsi.datapoint import save_datapoint
from dpsi.pointclouds import read_points
from dpsi.provenance import recorded
from dpsi.rawdata import read_dataset_config

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    row = snakemake.params.row
    effector = read_dataset_config(snakemake.params.raw)[2][row["effector"]].effector()
    trajectory, start = prepare.load_trajectory(snakemake.input.trajectory)
    save_datapoint(snakemake.output[0], prepare.assemble(
        snakemake.wildcards.id, row["motion"], effector, read_points(snakemake.input.particles),
        snakemake.params.density, trajectory, start, prepare.load_targets(snakemake.input.targets)))
