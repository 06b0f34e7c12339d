"""Identifiability ladder: how far the parameters that fit the data as well as the truth reach, per rung,
dataset, loss and parameter (table), and the landscapes around the truth (figure)."""

import pandas as pd

from dpsi.identifiability_landscape import COLUMNS, as_good_as_truth
from dpsi.landscapes import load_landscape
from dpsi.provenance import recorded
from dpsi.reporting.landscapes import plot_truth_landscapes
from dpsi.reporting.tables import write_table

out, p = snakemake.output, snakemake.params
with recorded(out, snakemake.input, dict(p), snakemake.log[0]):
    columns = [(f"{rung}, {dataset}", load_landscape(f))
               for (rung, dataset), f in zip(p.labels, snakemake.input.landscapes)]
    table = pd.concat([as_good_as_truth(landscape).assign(rung=rung, dataset=dataset)
                       for (rung, dataset), (_, landscape) in zip(p.labels, columns)], ignore_index=True)
    write_table(table[["rung", "dataset", *COLUMNS]], out.table[0],
                "Parameters as good as the truth: per rung, dataset, loss and parameter, how far the grid cells "
                "whose loss is no higher than at the truth reach (multiples of the truth), with the grid minimum")
    plot_truth_landscapes(columns, *out.figure)
