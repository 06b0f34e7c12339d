"""Other materials (SPEC §7.4): recovered parameters against the twin's ground truth, and the runs."""

from pathlib import Path

from dpsi.parameter_sources import resolve
from dpsi.provenance import recorded
from dpsi.reporting import figures, tables
from dpsi.reporting.runs import load_runs

out, p = snakemake.output, snakemake.params
with recorded(out, snakemake.input, dict(p), snakemake.log[0]):
    summaries, logs = load_runs(snakemake.input.summaries, snakemake.input.logs)
    twin = Path(snakemake.input.truth[0]).parent
    truths = {m: resolve("truth", twin, material=m).as_dict() for m in p.materials}
    loss, dataset, validation = summaries[0]["loss"], summaries[0]["dataset"], ", ".join(p.validation)
    tables.write_table(tables.materials_table(summaries, truths), out.table[0],
                       f"Recovered level-2 parameters of other materials ({loss}, {dataset}) against the truth; "
                       f"validation height-map distance (mm) on {validation}")
    figures.plot_runs(logs, 2, *out.figure, columns="material", truth=truths,
                      title=f"Other materials, level 2, {loss} on {dataset}: validation on {validation}")
