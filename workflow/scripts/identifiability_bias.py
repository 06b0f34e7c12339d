"""Identifiability ladder: where the bias of R1 and R2 comes from (height-map distances of each step to the
twin's true after surface) and where each loss has its minimum along E and σ_y on R1 and R2 data."""

from pathlib import Path

import numpy as np
import pandas as pd

from dpsi.datapoint import load_datapoint
from dpsi.identifiability import bias_sources, loss_minima
from dpsi.provenance import recorded
from dpsi.reporting.tables import write_table
from dpsi.simulation import Simulator, SimulatorConfig
from dpsi.twin import GROUND_TRUTH_FILE, load_ground_truth

out, p = snakemake.output, snakemake.params
with recorded(out, snakemake.input, dict(p), snakemake.log[0]):
    simulator = Simulator(SimulatorConfig(**p.simulator))
    sources, minima = [], []
    for finer, reconstructed, twin, after in zip(snakemake.input.datapoints, snakemake.input.reconstructed,
                                                 snakemake.input.twin, snakemake.input.after_clouds):
        dp, ground_truth = load_datapoint(finer), load_ground_truth(Path(twin) / GROUND_TRUTH_FILE)
        sources.append({"datapoint": dp.id, **bias_sources(simulator, dp, ground_truth, p.density, np.load(after))})
        for rung, data in (("R1", load_datapoint(reconstructed)), ("R2", dp)):
            minima.append(loss_minima(simulator, data, ground_truth.parameters).assign(rung=rung, datapoint=dp.id))
    write_table(pd.DataFrame(sources), out.sources[0],
                "Height-map distance (mm) to the twin's true after surface: of the captured target, of the true "
                "surface captured again without calibration error and also without depth noise, and of "
                "simulations at the truth from the twin's own particles, the true shape filled at the "
                "identification density, and the reconstructed particles")
    write_table(pd.concat(minima, ignore_index=True), out.minima[0],
                "Where each loss has its minimum along E and yield stress (one-parameter scans through the truth)")
