"""Appendix A (SPEC §7.7): the height-map loss and its negation against point-cloud losses at level 1."""

from dpsi.provenance import recorded
from dpsi.reporting import figures, tables
from dpsi.reporting.runs import load_runs

out = snakemake.output
with recorded(out, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    summaries, logs = load_runs(snakemake.input.summaries, snakemake.input.logs)
    tables.write_table(tables.heightmap_losses_table(summaries), out.table[0],
                       "Validation metrics (mm) at the best iteration per optimised loss, level 1")
    losses = ", ".join(dict.fromkeys(s["loss"] for s in summaries))
    figures.plot_runs(logs, 1, *out.figure, title=f"Appendix A, level 1: optimising {losses}")
