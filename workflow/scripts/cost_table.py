"""The computation cost table from the per-(motion, density) measurements."""

import json
from pathlib import Path

from dpsi.provenance import recorded
from dpsi.reporting.cost import cost_table
from dpsi.reporting.tables import write_table

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    records = [json.loads(Path(f).read_text()) for f in snakemake.input.records]
    table = cost_table(records, snakemake.params.iterations)
    write_table(table, snakemake.output.table[0], caption="Computation cost of the simulator (SPEC §7.6)")
