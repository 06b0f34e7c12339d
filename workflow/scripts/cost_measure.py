"""Time forward and backward passes of one motion at one particle density, and measure peak memory, in a
child process that runs nothing but the measurement (not Snakemake's script machinery)."""

import json

from dpsi.bench import run_isolated
from dpsi.files import atomic_output
from dpsi.provenance import recorded

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]) as log:
    record = run_isolated(snakemake.wildcards.motion, float(snakemake.wildcards.density),
                          snakemake.params.measured_iterations, snakemake.params.simulator)
    log.info("%s", json.dumps(record))
    with atomic_output(snakemake.output[0]) as tmp:
        tmp.write_text(json.dumps(record, indent=1))
