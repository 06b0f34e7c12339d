"""Targets stage: PRT and PCD targets and the height map of the after state."""

from dpsi import prepare
from dpsi.pointclouds import read_mesh, read_points
from dpsi.provenance import recorded
from dpsi.rawdata import read_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    checked = read_checked(snakemake.input.checked)
    targets = prepare.after_targets(read_mesh(snakemake.input.mesh), read_points(snakemake.input.points),
                                    read_points(snakemake.input.particles), snakemake.params.density,
                                    checked.table_z, checked.datapoints[0].after.measured)
    prepare.save_targets(snakemake.output[0], targets)
