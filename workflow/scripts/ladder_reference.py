"""Identifiability ladder: the loss at the truth and the validation height-map distances of the truth, the
hand-picked parameters and no motion, for one (rung, level, dataset)."""

import json
from pathlib import Path

from dpsi.datapoint import load_datapoint_sets
from dpsi.identifiability import reference
from dpsi.files import atomic_output
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig
from dpsi.twin_plan import load_truth

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    truth = load_truth(Path(snakemake.input.truth[0]).parent)["materials"]["clay"]
    training, validation = load_datapoint_sets(snakemake.input.training, snakemake.input.validation)
    result = reference(Simulator(SimulatorConfig(**snakemake.params.simulator)), training, validation, truth,
                       int(snakemake.wildcards.level))
    with atomic_output(snakemake.output[0]) as tmp:
        tmp.write_text(json.dumps(result, indent=1))
