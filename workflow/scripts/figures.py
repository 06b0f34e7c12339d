"""Figures: validation metrics and parameters over iterations per level; height maps and particles of
the out-of-distribution datapoints simulated with the first (loss, dataset)'s best parameters, and their
frames along the trajectory next to the hand-picked parameters' and the real captures; with uncertainty, the runs'
intervals."""

import json
from pathlib import Path

import numpy as np

from dpsi.datapoint import load_datapoint
from dpsi.provenance import recorded
from dpsi.reporting import figures, frames, tables
from dpsi.reporting.runs import load_runs

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    summaries, runs = load_runs(snakemake.input.summaries, snakemake.input.logs)
    if snakemake.output.uncertainty:
        figures.plot_intervals(tables.uncertainty_table(summaries), *snakemake.output.uncertainty,
                               "Estimates of the main sweep's runs and their intervals (solid: determined; dotted: "
                               "reaches a bound)")
    pngs = [p for p in snakemake.output.runs if p.endswith(".png")]
    for png in pngs:
        level = int(Path(png).stem.split("_L")[1])
        figures.plot_runs(runs, level, png, png[:-4] + ".pdf")
    if snakemake.input.ood:
        identified = [f for f in snakemake.input.ood if not f.endswith("hand-picked.json")][0]
        first = json.loads(Path(identified).read_text())[0]
        label = f"{first['loss']} / {first['dataset']}"
        hand_picked = [f for f in snakemake.input.ood if f.endswith("hand-picked.json")][0]
        with np.load(identified[:-5] + ".npz") as finals, np.load(hand_picked[:-5] + ".npz") as baseline:
            for path in snakemake.input.datapoints:
                dp = load_datapoint(path)
                for kind, plot in (("heightmaps", figures.plot_heightmaps), ("particles", figures.plot_particles)):
                    png = str(Path(snakemake.output.ood[0]).parent / f"{kind}_{dp.id}.png")
                    plot(dp, finals[dp.id], png, png[:-4] + ".pdf", title=f"{dp.id}, best level-2 θ of {label}")
                png = str(Path(snakemake.output.ood[0]).parent / f"frames_{dp.id}.png")
                simulated = {"hand-picked": baseline[f"{dp.id}.frames"], label: finals[f"{dp.id}.frames"]}
                frames.plot_frames(dp, simulated, finals[f"{dp.id}.steps"], png, png[:-4] + ".pdf")
