"""Assemble the prepared datapoint that identification reads."""

import numpy as np

from dpsi.datapoint import Datapoint, save_datapoint
from dpsi.motions import Trajectory
from dpsi.pointclouds import read_points
from dpsi.provenance import recorded

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    row = snakemake.params.row
    with np.load(snakemake.input.targets) as targets, np.load(snakemake.input.trajectory) as traj:
        datapoint = Datapoint(
            id=snakemake.wildcards.id, motion=row["motion"], effector=row["effector"],
            particles=read_points(snakemake.input.particles), particle_volume=1.0 / snakemake.params.density,
            trajectory=Trajectory(traj["positions"], traj["yaw"], float(traj["dt"])), start=traj["start"],
            table_z=float(targets["table_z"]), pcd_target=targets["pcd_target"], prt_target=targets["prt_target"],
            heightmap=targets["heightmap"], centre_xy=targets["centre_xy"])
    save_datapoint(snakemake.output[0], datapoint)
