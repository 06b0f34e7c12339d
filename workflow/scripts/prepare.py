"""Assemble the prepared datapoint that identification reads, after checking that it is a possible capture
(dpsi.plausibility: errors fail the job, warnings go to its log)."""

from dpsi import prepare
from dpsi.datapoint import save_datapoint
from dpsi.plausibility import check_plausible
from dpsi.pointclouds import read_points
from dpsi.provenance import recorded
from dpsi.rawdata import read_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]) as log:
    dataset = read_checked(snakemake.input.checked)
    datapoint = dataset.datapoints[0]
    trajectory, start = prepare.load_trajectory(snakemake.input.trajectory)
    prepared = prepare.assemble(
        datapoint.id, datapoint.motion, dataset.effectors[datapoint.effector].effector(),
        read_points(snakemake.input.particles), snakemake.params.density, trajectory, start,
        prepare.load_targets(snakemake.input.targets))
    shapes = (f"the before shape of {datapoint.id}", f"the after shape of {datapoint.id}")
    for warning in check_plausible(prepared, *shapes, f"the planner trajectory {datapoint.trajectory}",
                                   f"table_z in {dataset.root / 'dataset.yaml'}"):
        log.warning(f"warning: {warning}")
    save_datapoint(snakemake.output[0], prepared)
