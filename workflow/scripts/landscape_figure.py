"""Heat maps of the loss landscapes of one parameter pair, one column per dataset."""

from pathlib import Path

from dpsi.landscapes import load_landscape
from dpsi.provenance import recorded
from dpsi.reporting.landscapes import plot_landscapes

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    columns = [(Path(f).stem, load_landscape(f)) for f in snakemake.input.landscapes]  # .../<pair>/<dataset>.npz
    plot_landscapes(columns, snakemake.output.png, snakemake.output.pdf)
