"""Validate one raw datapoint (every file it uses, read once) and record what its stages need."""

from pathlib import Path

from dpsi.provenance import recorded
from dpsi.rawdata import load_raw_dataset, write_checked

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    datapoint = snakemake.wildcards.id
    write_checked(snakemake.output[0], load_raw_dataset(Path(snakemake.input[0]).parent, only=[datapoint]), datapoint)
