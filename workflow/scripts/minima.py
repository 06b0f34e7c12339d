"""Local minima (SPEC §7.5): random against hand-picked initial values at level 1."""

from dpsi.provenance import recorded
from dpsi.reporting import figures, tables
from dpsi.reporting.runs import load_runs

out = snakemake.output
with recorded(out, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    summaries, logs = load_runs(snakemake.input.summaries, snakemake.input.logs)
    loss = summaries[0]["loss"]
    tables.write_table(tables.minima_table(summaries), out.table[0],
                       f"Best validation height-map distance (mm), level 1, {loss}, from random and hand-picked "
                       f"initial values (the hand-picked run is the same for every seed: seed = {tables.ANY_SEED_LABEL})")
    figures.plot_runs(logs, 1, *out.figure, colours="start",
                      title=f"Local minima, level 1, {loss}: random vs hand-picked initial values")
