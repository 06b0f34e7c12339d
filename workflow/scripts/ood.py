"""Out-of-distribution motions simulated with the best level-2 parameters of one (loss, dataset) across
seeds, or with the hand-picked parameters when the rule gives no run summaries: height-map distances,
and per datapoint the final particles (key <id>) and frames along the trajectory (<id>.frames at the
steps <id>.steps)."""

import json

import numpy as np

from dpsi.datapoint import load_datapoint
from dpsi.heightmap import heightmap_distance_mm
from dpsi.identification import scene
from dpsi.losses import simulated_heightmap
from dpsi.parameter_sources import best_run
from dpsi.parameters import HAND_PICKED, Parameters
from dpsi.files import atomic_output
from dpsi.provenance import recorded
from dpsi.reporting.frames import frame_steps
from dpsi.reporting.runs import read_summary
from dpsi.reporting.tables import HAND_PICKED_LABEL
from dpsi.simulation import Simulator, SimulatorConfig

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]) as log:
    if snakemake.input.summaries:
        summaries = [read_summary(f) for f in snakemake.input.summaries]  # one (loss, dataset), its seeds
        params = Parameters.checked(**best_run(summaries)["parameters"])
        loss, dataset = summaries[0]["loss"], summaries[0]["dataset"]
    else:
        params, loss, dataset = HAND_PICKED, HAND_PICKED_LABEL, ""
    simulator = Simulator(SimulatorConfig(**snakemake.params.simulator))
    records, finals = [], {}
    for path in snakemake.input.datapoints:
        dp = load_datapoint(path)
        final = simulator.forward(scene(dp), params, keep_substeps=False)
        distance = heightmap_distance_mm(simulated_heightmap(final, dp.heightmap_target()), dp.heightmap)
        records.append({"motion": dp.motion, "config": dp.id, "loss": loss, "dataset": dataset,
                        "parameters": params.as_dict(), "heightmap_mm": distance})
        finals[dp.id] = final
        steps = frame_steps(dp.trajectory.n_steps)
        finals[f"{dp.id}.steps"], finals[f"{dp.id}.frames"] = steps, simulator.positions_at(steps)
        log.info("%s: height-map distance %.1f mm", dp.id, distance)
    with atomic_output(snakemake.output.records) as tmp:
        tmp.write_text(json.dumps(records, indent=1))
    with atomic_output(snakemake.output.particles) as tmp, open(tmp, "wb") as f:
        np.savez(f, **finals)
