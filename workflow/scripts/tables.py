"""The paper's tables from the run summaries, the hand-picked baseline and the OOD evaluations."""

import json
from pathlib import Path

from dpsi import generalisation
from dpsi.provenance import recorded
from dpsi.reporting import tables
from dpsi.reporting.runs import read_summary

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    summaries = [read_summary(path) for path in snakemake.input.summaries]
    baselines = {(record["level"], record["id"]): record
                 for record in (json.loads(Path(f).read_text()) for f in snakemake.input.baselines)}
    compared = [row for summary, unseen in zip(summaries, snakemake.input.unseen)
                for row in generalisation.comparison_rows(summary, json.loads(Path(unseen).read_text()), baselines)]
    ood = [record for f in snakemake.input.ood for record in json.loads(Path(f).read_text())]
    out = Path(snakemake.output[0]).parent
    tables.write_table(tables.motions_table(), out / "motions.csv", "Motions (SPEC §2)")
    tables.write_table(tables.parameters_table(), out / "parameters.csv", "Parameter ranges and Adam step sizes")
    tables.write_table(tables.best_params_table(summaries, baselines, generalisation.recommend(compared)),
                       out / "best_params.csv",
                       "Parameters at the lowest validation height-map distance (mm), with their intervals where measured")
    tables.write_table(tables.generalisation_table(compared), out / "generalisation.csv",
                       "Height-map distance (mm) on the datapoints each run did not train on")
    tables.write_table(tables.ood_table(ood), out / "ood_heightmap.csv",
                       "Out-of-distribution height-map distance (mm)")
    tables.write_table(tables.recovery_table(summaries), out / "recovery_error.csv",
                       "Relative error of recovered parameters against the twin's ground truth")
    if any(Path(f).name == "uncertainty.csv" for f in snakemake.output):
        tables.write_table(tables.uncertainty_table(summaries), out / "uncertainty.csv",
                           "What each run's data determine: per quantity the estimate and its interval (not determined "
                           "where it reaches a bound of the range)")
