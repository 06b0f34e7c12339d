"""Particle filling stage: before mesh → particles at the configured density."""

from dpsi import prepare
from dpsi.pointclouds import read_mesh, write_points
from dpsi.provenance import recorded

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    mesh = read_mesh(snakemake.input.mesh)
    particles = prepare.fill_particles(mesh, snakemake.params.density, f"{snakemake.wildcards.id} before mesh")
    write_points(snakemake.output[0], particles)
