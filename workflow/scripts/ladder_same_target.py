"""Identifiability ladder R0: the run of a PCD loss is the run of its PRT loss (the same targets at R0),
relabelled (dpsi.identifiability.relabelled)."""

import json
import shutil
from pathlib import Path

from dpsi.files import atomic_output
from dpsi.identifiability import relabelled
from dpsi.provenance import recorded

out = snakemake.output
with recorded(out, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    summary = relabelled(json.loads(Path(snakemake.input.summary).read_text()), snakemake.params.loss)
    with atomic_output(out.summary) as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
    with atomic_output(out.log) as tmp:
        shutil.copyfile(snakemake.input.log, tmp)
