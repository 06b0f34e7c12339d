"""Resolution study: the convergence table over the configured grid cells."""

from dpsi.convergence import TOLERANCE_MM, recommended_dx_mm, resolution_study
from dpsi.provenance import recorded
from dpsi.reporting.tables import write_table

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]) as log:
    table = resolution_study(snakemake.params.dx_mm, snakemake.params.motions,
                             simulator=snakemake.params.simulator, log=log.info)
    log.info("coarsest dx within %g mm of the finest: %g mm", TOLERANCE_MM, recommended_dx_mm(table))
    write_table(table, snakemake.output.table[0], caption="Resolution study: clay truth, round effector; "
                "height-map distances (mm) to the finest dx, dent depth (mm), forward time (s)")
