"""Validation metrics of the hand-picked literature parameters (the baseline of the main table)."""

import json

from dpsi.datapoint import load_datapoint
from dpsi.identification import validation
from dpsi.parameters import HAND_PICKED
from dpsi.files import atomic_output
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    simulator = Simulator(SimulatorConfig(**snakemake.params.simulator))
    metrics, failed = validation(simulator, [load_datapoint(f) for f in snakemake.input.validation], HAND_PICKED)
    with atomic_output(snakemake.output[0]) as tmp:
        tmp.write_text(json.dumps({"level": int(snakemake.wildcards.level), "parameters": HAND_PICKED.as_dict(), "validation": metrics, "failed": failed}))
