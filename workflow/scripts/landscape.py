"""The loss landscape of one (parameter pair, dataset), the other parameters from the configured source."""

from dpsi import landscape_compute, landscapes
from dpsi.datapoint import load_datapoint
from dpsi.parameter_sources import resolve_from_files
from dpsi.parameters import at_level
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig

w, p = snakemake.wildcards, snakemake.params
with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]) as log:
    pair = landscapes.pair_by_name(w.pair)
    fixed = at_level(resolve_from_files(p.fixed, snakemake.input.fixed), pair.level)
    log.info("%s landscape on %s, other parameters %s", w.pair, w.dataset, fixed.as_dict())
    landscape = landscape_compute.compute(Simulator(SimulatorConfig(**p.simulator)),
                                           [load_datapoint(f) for f in snakemake.input.datapoints],
                                           pair, fixed, p.resolution, p.losses)
    landscapes.save_landscape(snakemake.output[0], landscape)
