"""Identifiability ladder R1: the twin datapoint simulated at the identification resolution, captured and
reconstructed as a robot's would be."""

from pathlib import Path

from dpsi.datapoint import save_datapoint
from dpsi.identifiability import reconstructed_twin_datapoint
from dpsi.provenance import recorded
from dpsi.simulation import SimulatorConfig
from dpsi.twin import MotionError
from dpsi.twin_plan import load_truth, plan_from_config

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    twin, p = snakemake.params.twin, snakemake.params
    materials = load_truth(Path(snakemake.input.truth[0]).parent)["materials"]
    config = SimulatorConfig(**{**p.simulator, "max_particles": twin["max_particles"]})
    datapoint = reconstructed_twin_datapoint(snakemake.output.raw, snakemake.wildcards.id,
                                             plan_from_config(twin["groups"]), twin["seed"], config, p.density,
                                             materials, MotionError(**p.motion_error))
    save_datapoint(snakemake.output.prepared, datapoint)
