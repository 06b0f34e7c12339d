"""Import the published real clay pairs as a raw dataset; the record lists each pair's place and repairs."""

import json
from pathlib import Path

from dpsi.files import atomic_output
from dpsi.provenance import recorded
from dpsi.release import import_release
from dpsi.release_plan import ImportTables

p = snakemake.params
with recorded(snakemake.output, snakemake.input, dict(p), snakemake.log[0]):
    records = import_release(p.source, Path(snakemake.output.table).parent, ImportTables.from_config(p.release),
                             seed=p.release.get("seed", 0))
    with atomic_output(snakemake.output.record) as tmp:
        tmp.write_text(json.dumps(records, indent=1))
