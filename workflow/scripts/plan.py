"""Greedy plan (SPEC §7.8) from a prepared datapoint's before state towards its captured after height map."""

from dpsi.datapoint import load_datapoint
from dpsi.effectors import by_name
from dpsi.parameter_sources import resolve_from_files
from dpsi.planning import ActionSet, Planner, save_plan
from dpsi.provenance import recorded
from dpsi.simulation import Simulator, SimulatorConfig

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]) as log:
    settings = snakemake.params.planning
    params = resolve_from_files(settings["parameters"], snakemake.input.parameters)
    log.info("parameters %s: %s", settings["parameters"], params.as_dict())
    dp = load_datapoint(snakemake.input.datapoint[0])
    actions = ActionSet(tuple(settings["motions"]), by_name(settings["effector"]), settings["grid"],
                        settings["spacing"])
    planner = Planner(Simulator(SimulatorConfig(**snakemake.params.simulator)), params, actions,
                      dp.particle_volume, dp.table_z)
    plan = planner.plan(dp.particles, dp.heightmap_target(), settings["actions"])
    log.info("height-map distance %.1f mm → %.1f mm", plan.initial_distance_mm, plan.final_distance_mm)
    save_plan(snakemake.output.record, snakemake.output.arrays, plan, datapoint=dp.id,
              parameter_source=settings["parameters"], parameters=params.as_dict(), motions=settings["motions"],
              effector=settings["effector"], grid=settings["grid"], spacing=settings["spacing"])
