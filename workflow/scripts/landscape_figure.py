"""Heat maps of the loss landscapes of one parameter pair, one column per dataset."""

from dpsi.landscapes import load_landscape
from dpsi.provenance import recorded
from dpsi.reporting.landscapes import plot_landscapes

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    columns = [(dataset, load_landscape(f)) for dataset, f in zip(snakemake.params.datasets, snakemake.input.landscapes)]
    plot_landscapes(columns, *snakemake.output)
