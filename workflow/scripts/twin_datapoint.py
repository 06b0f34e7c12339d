"""Simulate and capture one datapoint of the synthetic twin."""

from pathlib import Path

from dpsi import twin
from dpsi.provenance import recorded

folder = Path(snakemake.output[0])
with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    twin.generate_datapoint(folder.parent, folder.name)
