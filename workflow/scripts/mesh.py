"""Meshing stage: fused cloud → watertight mesh by ball pivoting (or the given mesh)."""

from dpsi import prepare
from dpsi.pointclouds import read_points, write_mesh
from dpsi.provenance import recorded
from dpsi.rawdata import read_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    source = getattr(read_checked(snakemake.input.checked).datapoints[0], snakemake.wildcards.state)
    name = f"{snakemake.wildcards.id} {snakemake.wildcards.state}"
    write_mesh(snakemake.output[0], prepare.state_mesh(source, read_points(snakemake.input.points), name))
