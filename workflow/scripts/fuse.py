"""Fusion stage: one state's camera views → closed fused cloud (or the given cloud / mesh surface)."""

from dpsi import prepare
from dpsi.pointclouds import write_points
from dpsi.provenance import recorded
from dpsi.rawdata import read_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    dataset = read_checked(snakemake.input.checked)
    datapoint = dataset.datapoints[0]
    source = getattr(datapoint, snakemake.wildcards.state)
    name = f"{datapoint.id} {snakemake.wildcards.state}"
    write_points(snakemake.output[0], prepare.state_points(source, dataset.workspace, dataset.table_z, name))
