"""Identifiability ladder table and figure: recovered parameters and their errors per rung, loss and seed."""

import json

from dpsi.identifiability import ladder_table
from dpsi.provenance import recorded
from dpsi.reporting import figures, tables
from dpsi.reporting.runs import load_runs

out, p = snakemake.output, snakemake.params
with recorded(out, snakemake.input, dict(p), snakemake.log[0]):
    summaries, logs = load_runs(snakemake.input.summaries, snakemake.input.logs, p.labels)
    references = {(labels["rung"], labels["level"], labels["dataset"]): json.loads(open(path).read())
                  for path, labels in p.references.items()}
    table = ladder_table(summaries, logs, references)
    tables.write_table(table, out.table, "Identifiability ladder: parameters recovered on the synthetic twin per "
                       "rung (R0 same model, R1 reconstructed, R2 finer twin), loss and seed; losses and "
                       "distances in mm")
    figures.plot_recovery(table, out.png, out.pdf)
