"""Identifiability ladder: the ladder's losses over (E, σ_y) around the truth on one rung's level-1 training
datapoints of one dataset."""

from pathlib import Path

from dpsi.datapoint import load_datapoint
from dpsi.identifiability_landscape import truth_landscape
from dpsi.landscapes import save_landscape
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig
from dpsi.twin_plan import load_truth

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    truth = load_truth(Path(snakemake.input.truth[0]).parent)["materials"]["clay"]
    landscape = truth_landscape(Simulator(SimulatorConfig(**snakemake.params.simulator)),
                                [load_datapoint(f) for f in snakemake.input.training], truth, snakemake.params.losses)
    save_landscape(snakemake.output[0], landscape)
