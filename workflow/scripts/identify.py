"""One identification run (level, loss, dataset, seed; for the analyses also material and start, for the
identifiability ladder its rung), resumable from its state file; its summary carries these labels."""

import sys
from pathlib import Path

from dpsi import identification
from dpsi.datapoint import load_datapoint_sets
from dpsi.parameters import HAND_PICKED
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig
from dpsi.twin_plan import load_truth

w, p = snakemake.wildcards, snakemake.params
labels = {**dict(w.items()), "level": int(w.level), "seed": int(w.seed), "start": p.initial,
          "material": w.get("material", "clay")}
with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    # a datapoint in both sets is one object, so that validation reuses its training simulation
    training, validation = load_datapoint_sets(snakemake.input.training, snakemake.input.validation)
    truth = load_truth(Path(snakemake.input.truth[0]).parent)["materials"]["clay"] if snakemake.input.truth else None
    identification.identify(
        Path(snakemake.output.summary).parent, int(w.level), w.loss, training,
        validation, seed=int(w.seed), iterations=p.iterations,
        initial=HAND_PICKED if p.initial == "hand-picked" else None, truth=truth,
        simulator=Simulator(SimulatorConfig(**p.simulator)), progress=sys.stderr, restart_if_different=True,
        labels=labels, known=p.known, select=p.select, uncertainty=p.uncertainty)
