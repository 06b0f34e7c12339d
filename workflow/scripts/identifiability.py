"""Identifiability ladder table and figure: recovered parameters and their errors per rung, loss and seed; with the
runs' uncertainty, their intervals (table and figure) and how often those of determined quantities hold the truth."""

import json

from dpsi.identifiability import ladder_table
from dpsi.provenance import recorded
from dpsi.reporting import figures, tables
from dpsi.reporting.runs import load_runs
from dpsi.uncertainty import coverage

out, p = snakemake.output, snakemake.params
with recorded(out, snakemake.input, dict(p), snakemake.log[0]):
    summaries, logs = load_runs(snakemake.input.summaries, snakemake.input.logs)
    references = {(labels["rung"], labels["level"], labels["dataset"]): json.loads(open(path).read())
                  for path, labels in p.references.items()}
    table = ladder_table(summaries, logs, references)
    tables.write_table(table, out.table[0], "Identifiability ladder: parameters recovered on the synthetic twin per "
                       "rung (R0 same model, R1 reconstructed, R2 finer twin), loss and seed; losses and "
                       "distances in mm")
    figures.plot_recovery(table, *out.figure)
    if out.uncertainty:
        intervals = tables.uncertainty_table(summaries)
        tables.write_table(intervals, out.uncertainty[0], "What each ladder run's data determine: per quantity the "
                           "estimate, its interval (low–high; not determined where it reaches a bound of the range) and "
                           "the truth")
        tables.write_table(coverage(intervals), out.uncertainty[3], "Coverage of the truth by the intervals marked "
                           "determined, per rung and quantity, and their median ×/÷ factor")
        figures.plot_intervals(intervals, *out.uncertainty[6:8], "Identifiability ladder: estimates and intervals "
                               "(solid: determined; dotted: reaches a bound) and the truth (×)")
