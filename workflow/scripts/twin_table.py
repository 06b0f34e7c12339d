"""Write the synthetic twin's datapoints table, layout and ground truth."""

from pathlib import Path

from dpsi import twin
from dpsi.provenance import recorded
from dpsi.simulation import SimulatorConfig
from dpsi.twin_plan import plan_from_config

settings = snakemake.params.twin
with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    twin.write_twin_table(Path(snakemake.output.table).parent, plan_from_config(settings["groups"]),
                          seed=settings["seed"], density=settings["density"],
                          config=SimulatorConfig(dx=settings["dx"], max_particles=settings["max_particles"]),
                          motion_error=twin.MotionError(**settings["motion_error"]))
