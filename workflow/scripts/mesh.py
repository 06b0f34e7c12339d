"""Meshing stage: fused cloud → watertight mesh by ball pivoting (or the given mesh)."""

from pathlib import Path

from dpsi import prepare
from dpsi.pointclouds import read_points, write_mesh
from dpsi.provenance import recorded
from dpsi.rawdata import load_raw_dataset

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    dataset = load_raw_dataset(Path(snakemake.input[0]).parent, only=[snakemake.wildcards.id])
    source = getattr(dataset.datapoint(snakemake.wildcards.id), snakemake.wildcards.state)
    name = f"{snakemake.wildcards.id} {snakemake.wildcards.state}"
    write_mesh(snakemake.output[0], prepare.state_mesh(source, read_points(snakemake.input.points), name))
