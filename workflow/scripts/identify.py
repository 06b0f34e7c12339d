"""One identification run (level, loss, dataset, seed), resumable from its state file."""

import sys
from pathlib import Path

from dpsi import identification
from dpsi.datapoint import load_datapoint
from dpsi.parameters import HAND_PICKED
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig
from dpsi.twin import read_truth

w, p = snakemake.wildcards, snakemake.params
with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    training = [load_datapoint(f) for f in snakemake.input.training]
    truth = read_truth(Path(snakemake.input.truth[0]).parent)[0]["clay"] if snakemake.input.truth else None
    identification.identify(
        Path(snakemake.output.summary).parent, int(w.level), w.loss, training,
        [load_datapoint(f) for f in snakemake.input.validation], seed=int(w.seed), iterations=p.iterations,
        initial=HAND_PICKED if p.initial == "hand-picked" else None, truth=truth,
        simulator=Simulator(SimulatorConfig(**p.simulator)), progress=sys.stderr, restart_if_different=True)
