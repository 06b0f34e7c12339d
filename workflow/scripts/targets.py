"""Targets stage: PRT and PCD targets and the height map of the after state."""

from pathlib import Path

import numpy as np

from dpsi import prepare
from dpsi.pointclouds import atomic_output, read_mesh, read_points
from dpsi.provenance import recorded
from dpsi.rawdata import load_raw_dataset

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    table_z = load_raw_dataset(Path(snakemake.input.layout).parent, only=[snakemake.wildcards.id]).table_z
    particles = read_points(snakemake.input.particles)
    centre = prepare.footprint_centre(particles)
    prt, pcd, heightmap = prepare.targets(read_mesh(snakemake.input.mesh), read_points(snakemake.input.points),
                                          len(particles), snakemake.params.density, centre, table_z)
    with atomic_output(snakemake.output[0]) as tmp, open(tmp, "wb") as f:
        np.savez(f, prt_target=prt, pcd_target=pcd, heightmap=heightmap, centre_xy=centre, table_z=table_z)
