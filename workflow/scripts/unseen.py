"""A run's selected parameters on every datapoint it did not train on."""

import json

from dpsi.baselines import on_unseen
from dpsi.datapoint import load_datapoint
from dpsi.files import atomic_output
from dpsi.identification import METRICS
from dpsi.parameters import Parameters
from dpsi.provenance import recorded
from dpsi.reporting.runs import read_summary
from dpsi.simulation import Simulator, SimulatorConfig

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    best = read_summary(snakemake.input.summary)["best"]
    datapoints = [load_datapoint(f) for f in snakemake.input.datapoints]
    # a run that selected no iteration predicts nothing: its rows stay empty (NaN) rather than show its start
    records = (on_unseen(Simulator(SimulatorConfig(**snakemake.params.simulator)), datapoints,
                         Parameters(**best["parameters"])) if best else
               [{"id": dp.id, **dict.fromkeys(METRICS, float("nan"))} for dp in datapoints])
    with atomic_output(snakemake.output[0]) as tmp:
        tmp.write_text(json.dumps(records, indent=1))
