"""Identifiability ladder R0: a prepared datapoint whose targets are the identification simulator's own
result at the truth."""

from pathlib import Path

from dpsi.datapoint import load_datapoint, save_datapoint
from dpsi.identifiability import same_model_datapoint
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig
from dpsi.twin_plan import load_truth

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    truth = load_truth(Path(snakemake.input.truth[0]).parent)["materials"][snakemake.params.material]
    simulator = Simulator(SimulatorConfig(**snakemake.params.simulator))
    save_datapoint(snakemake.output[0], same_model_datapoint(load_datapoint(snakemake.input.datapoint), simulator, truth))
