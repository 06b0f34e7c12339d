"""Figures: validation metrics and parameters over iterations per level; height maps and particles of
the out-of-distribution datapoints simulated with the first (loss, dataset)'s best parameters, and their
frames along the trajectory next to the hand-picked parameters' and the real captures."""

from pathlib import Path

import numpy as np
import pandas as pd

from dpsi.datapoint import load_datapoint
from dpsi.provenance import recorded
from dpsi.reporting import figures, frames

with recorded(snakemake.output, snakemake.input, dict(snakemake.params), snakemake.log[0]):
    logs = []
    for path in map(Path, snakemake.input.logs):  # .../runs/L<level>/<loss>/<dataset>/seed<seed>/log.csv
        level, loss, dataset, seed = int(path.parts[-5][1:]), path.parts[-4], path.parts[-3], int(path.parts[-2][4:])
        logs.append(pd.read_csv(path).assign(level=level, loss=loss, dataset=dataset, seed=seed))
    runs = pd.concat(logs, ignore_index=True)
    pngs = [p for p in snakemake.output.runs if p.endswith(".png")]
    for png in pngs:
        level = int(Path(png).stem.split("_L")[1])
        figures.plot_runs(runs, level, png, png[:-4] + ".pdf")
    if snakemake.input.ood:
        identified = [f for f in snakemake.input.ood if not f.endswith("hand-picked.json")][0]
        label = " / ".join(Path(identified).with_suffix("").parts[-2:])
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
