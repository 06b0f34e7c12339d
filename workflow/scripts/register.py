"""Register a datapoint's motion offset from the dent in its after scan; write it with its path moved."""

import json

from dpsi.datapoint import load_datapoint, save_datapoint
from dpsi.files import atomic_output
from dpsi.motion_offsets import register, shifted
from dpsi.parameters import hand_picked
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig

p = snakemake.params
with recorded(snakemake.output, snakemake.input, dict(p), snakemake.log[0]):
    datapoint = load_datapoint(snakemake.input.datapoint)
    registration = register(Simulator(SimulatorConfig(**p.simulator)), datapoint, hand_picked(p.level))
    save_datapoint(snakemake.output.datapoint, shifted(datapoint, registration.offset))
    with atomic_output(snakemake.output.record) as tmp:
        tmp.write_text(json.dumps({**registration.as_dict(), "parameters": hand_picked(p.level).as_dict()}, indent=1))
