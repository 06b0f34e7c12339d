"""The baselines of one datapoint for runs of one level: the hand-picked values and no motion."""

import json

from dpsi.baselines import baseline
from dpsi.datapoint import load_datapoint
from dpsi.files import atomic_output
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    record = baseline(Simulator(SimulatorConfig(**snakemake.params.simulator)), load_datapoint(snakemake.input.datapoint),
                      int(snakemake.wildcards.level))
    with atomic_output(snakemake.output[0]) as tmp:
        tmp.write_text(json.dumps(record, indent=1))
