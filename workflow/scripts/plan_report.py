"""The planning table and figure (SPEC §7.8) from a saved plan."""

from dpsi.planning import load_plan
from dpsi.provenance import recorded
from dpsi.reporting.planning import planning_table, plot_plan
from dpsi.reporting.tables import write_table

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    plan, record = load_plan(snakemake.input.record, snakemake.input.arrays)
    write_table(planning_table(record), snakemake.output.table[0],
                caption="Greedy plan towards a flattened shape's height map: the distance (mm) after every action.")
    plot_plan(plan, *snakemake.output.figure,
              title=f"plan from {record['datapoint']} ({record['effector']} effector)")
