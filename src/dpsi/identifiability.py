"""The identifiability ladder: how far identification gets from the truth, one source of error at a time.

On the synthetic twin the truth θ* is known, so a run's error can be traced to what stands between the true
object and the simulator. Three rungs share the datapoints (same lumps, trajectories, training and
validation sets) and differ only in how the targets come about:

- **R0, same model**: the targets are the identification simulator's own final particles at θ*, from the
  particles it starts with (PCD and PRT targets are those particles, the height map theirs). Every loss is
  zero at θ*, so a run that misses θ* here has a gradient, step-size or identifiability problem.
- **R1, reconstructed**: the twin simulated at the identification's own resolution (cell size and particle
  density), its targets made as for a robot: capture → fusion → meshing → filling.
- **R2, finer twin**: the main pipeline's datapoints, whose twin is simulated finer than identification.

For each run the ladder reports the recovered parameters and their relative errors, the training loss at θ*
and at the estimate, and the validation height-map distance next to those of the hand-picked parameters
and of no motion at all. Units: mm for losses and distances, SI for parameters.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from dpsi.datapoint import Datapoint
from dpsi.heightmap import heightmap_distance_mm
from dpsi.identification import evaluate, scene, targets
from dpsi.landscapes import SCAN_FACTORS, scan_values
from dpsi.losses import loss_by_name, simulated_heightmap
from dpsi.parameters import IDENTIFIED, Parameters, at_level, hand_picked, scale_free
from dpsi.simulation import Simulator, SimulatorConfig

RUNGS = {
    "R0": "same model: targets are the identification simulator's own result at the truth",
    "R1": "reconstructed: twin at the identification resolution, targets through capture and reconstruction",
    "R2": "finer twin: the main pipeline's datapoints, twin simulated finer than identification",
    "R1m": "R1 with motion error: the twin's tool strays from the path the datapoint records (motion_error)",
    "R1r": "R1m with each datapoint's motion offset registered from its dent (dpsi.motion_offsets) first",
}
"""The rungs, from the easiest to the real pipeline."""

LADDER_LOSSES = ("pcd_cd", "prt_cd", "pcd_emd", "prt_emd", "heightmap", "heightmap_interior")
"""The training losses whose value at the truth the ladder reports: the four of SPEC §5, the height map and
the height map inside the outlines."""

COLUMNS = ("rung", "level", "loss", "dataset", "seed", "parameter", "truth", "estimate", "rel_error",
           "loss_at_truth_mm", "loss_at_estimate_mm", "val_heightmap_mm", "val_heightmap_hand_picked_mm",
           "val_heightmap_no_motion_mm", "low", "high", "determined")
"""Columns of the ladder table: one row per run and identified parameter, and per scale-free combination
(:data:`dpsi.parameters.SCALE_FREE`: E/rho, yield_stress/E) of the identified ones; ``low``, ``high`` and
``determined``: the quantity's interval where the run measured it (:mod:`dpsi.uncertainty`), else empty."""


SAME_AT_R0 = {"pcd_cd": "prt_cd", "pcd_emd": "prt_emd"}
"""At R0 the PCD and the PRT target are the same particles, so each key is the same loss as its value there:
the ladder runs the value once and reports the run under both names (:func:`relabelled`)."""


def relabelled(summary: dict, loss: str) -> dict:
    """The summary of an R0 run of ``SAME_AT_R0[loss]`` labelled as the run of ``loss``, the same function at
    R0 (the run would repeat it bit for bit); ``same_run_as`` names the loss that was run."""
    labels = summary.get("labels", {})
    if labels.get("rung") != "R0" or SAME_AT_R0.get(loss) != summary.get("loss"):
        raise ValueError(f"only an R0 run of {SAME_AT_R0.get(loss, 'a PRT loss')!r} stands for {loss!r}; "
                         f"this is a {labels.get('rung')} run of {summary.get('loss')!r}")
    return {**summary, "loss": loss, "labels": {**labels, "loss": loss}, "same_run_as": summary["loss"]}


def check_rung(rung: str) -> str:
    """``rung`` if it is one of :data:`RUNGS`, else a ValueError listing them."""
    if rung not in RUNGS:
        raise ValueError(f"unknown rung {rung!r}; the ladder's rungs are {list(RUNGS)}")
    return rung


def same_model_datapoint(dp: Datapoint, simulator: Simulator, truth: Parameters) -> Datapoint:
    """R0: ``dp`` with its targets replaced by the simulator's own final particles at ``truth`` (both point
    targets are those particles; the height map is theirs, drawn as particle cubes)."""
    final = simulator.forward(scene(dp), truth, keep_substeps=False)
    return dataclasses.replace(dp, pcd_target=final.copy(), prt_target=final.copy(),
                               heightmap=simulated_heightmap(final, dp.heightmap_target()))


def reconstructed_twin_datapoint(root: str | os.PathLike, datapoint_id: str, plan, seed: int,
                                 config: SimulatorConfig, density: float,
                                 materials: Mapping[str, Parameters], motion_error=None) -> Datapoint:
    """R1: the twin datapoint ``datapoint_id`` of ``plan`` (same lump and trajectory as the main twin with
    ``seed`` and ground truth ``materials``) simulated with the identification's ``config`` and ``density``
    (particles/m³) under ``root``, then reconstructed from its camera views and prepared at ``density``.
    R1m: the same with the twin's tool straying from the recorded path by ``motion_error``
    (:class:`dpsi.twin.MotionError`)."""
    from dpsi.prepare import prepare_datapoint  # open3d and pymeshlab: only this rung needs them
    from dpsi.rawdata import load_raw_dataset
    from dpsi.twin import generate_datapoint, write_twin_table

    write_twin_table(root, plan, seed, dict(materials), config, density, motion_error)
    generate_datapoint(root, datapoint_id)
    return prepare_datapoint(load_raw_dataset(root, only=[datapoint_id]), datapoint_id, density)


def level_truth(truth: Parameters, level: int) -> Parameters:
    """The truth as a run of ``level`` can reach it: level 1 holds the frictions at their fixed values."""
    return at_level(truth, level)


def reference(simulator: Simulator, training: Sequence[Datapoint], validation: Sequence[Datapoint],
              truth: Parameters, level: int) -> dict:
    """What a run of ``level`` on these datapoints is compared with: the mean training loss (mm) of each of
    :data:`LADDER_LOSSES` at the truth, and the mean validation height-map distance (mm) of the truth, of
    the hand-picked parameters (frictions as the level holds them) and of no motion (the before particles)."""
    truth = level_truth(truth, level)
    finals = [simulator.forward(scene(dp), truth, keep_substeps=False) for dp in training]
    loss_at_truth = {loss: float(np.mean([loss_by_name(loss)(final, targets(dp))[0]
                                          for final, dp in zip(finals, training)])) for loss in LADDER_LOSSES}
    at_truth = {id(dp): final for dp, final in zip(training, finals)}  # a validation datapoint may be a training one

    def val_heightmap(params: Parameters, simulated: dict[int, np.ndarray]) -> float:
        return float(np.mean([evaluate(simulator, dp, params, simulated.get(id(dp)))["heightmap_mm"]
                              for dp in validation]))

    no_motion = float(np.mean([heightmap_distance_mm(simulated_heightmap(dp.particles, dp.heightmap_target()),
                                                     dp.heightmap) for dp in validation]))
    return {"level": level, "truth": truth.as_dict(), "loss_at_truth_mm": loss_at_truth,
            "val_heightmap_truth_mm": val_heightmap(truth, at_truth),
            "val_heightmap_hand_picked_mm": val_heightmap(hand_picked(level), {}),
            "val_heightmap_no_motion_mm": no_motion}


def run_rows(summary: dict, log: pd.DataFrame, ref: dict) -> list[dict]:
    """Ladder-table rows of one run: its ``summary`` (:func:`dpsi.identification.summarise` with the labels
    rung, level, loss, dataset and seed), its ``log`` rows (for the training loss at the best row) and the
    ``ref`` of its (rung, level, dataset) from :func:`reference`. Parameters the run held ``known`` get no
    row; the scale-free combinations still use their values."""
    level, loss, best = int(summary["level"]), summary["loss"], summary["best"]
    at_best = log.loc[log["iteration"] == best["iteration"], "train_loss_mm"] if best else []
    common = {"rung": check_rung(summary["rung"]), "level": level, "loss": loss, "dataset": summary["dataset"],
              "seed": int(summary["seed"]), "loss_at_truth_mm": ref["loss_at_truth_mm"].get(loss, math.nan),
              "loss_at_estimate_mm": float(at_best.iloc[0]) if len(at_best) else math.nan,
              "val_heightmap_mm": best["validation"]["heightmap_mm"] if best else math.nan,
              "val_heightmap_hand_picked_mm": ref["val_heightmap_hand_picked_mm"],
              "val_heightmap_no_motion_mm": ref["val_heightmap_no_motion_mm"]}
    truth = {name: ref["truth"][name] for name in IDENTIFIED[level]}
    estimate = {name: best["parameters"][name] if best else math.nan for name in IDENTIFIED[level]}
    truth.update(scale_free(truth))
    estimate.update(scale_free(estimate))
    held = set(summary.get("known", ()))  # held at given values, not recovered: no row of their own
    measured = {q["quantity"]: q for q in (summary.get("uncertainty") or {}).get("quantities", [])}
    unmeasured = {"low": math.nan, "high": math.nan, "determined": None}
    return [{**common, "parameter": name, "truth": truth[name], "estimate": estimate[name],
             "rel_error": abs(estimate[name] - truth[name]) / abs(truth[name]),
             **({k: measured[name][k] for k in unmeasured} if name in measured else unmeasured)}
            for name in truth if name not in held]


RUN_LABELS = ("rung", "level", "loss", "dataset", "seed")


def ladder_table(summaries: Sequence[dict], logs: pd.DataFrame, references: Mapping[tuple, dict]) -> pd.DataFrame:
    """The ladder table (:data:`COLUMNS`): the rows of every run, sorted by rung, level, loss, dataset and
    seed. ``summaries`` carry the :data:`RUN_LABELS`, ``logs`` holds every run's log rows with the labels as
    columns, ``references`` maps (rung, level, dataset) to :func:`reference`'s result."""
    rows = []
    for summary in summaries:
        mine = np.logical_and.reduce([logs[k] == summary[k] for k in RUN_LABELS])
        ref = references[(summary["rung"], int(summary["level"]), summary["dataset"])]
        rows += run_rows(summary, logs[mine], ref)
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    return table.sort_values(list(RUN_LABELS), kind="stable").reset_index(drop=True)


def recovery_summary(table: pd.DataFrame) -> pd.DataFrame:
    """Median relative error per (rung, level, dataset, loss) and parameter over seeds (the ladder at a
    glance, for a notebook or the README)."""
    by_run = table.groupby(["rung", "level", "dataset", "loss", "parameter"])
    return by_run["rel_error"].median().unstack("parameter")


SCAN_PARAMETERS = ("E", "yield_stress")
"""The one-parameter scans of :func:`loss_minima`: these parameters at :data:`SCAN_FACTORS` times the truth."""


def bias_sources(simulator: Simulator, dp: Datapoint, ground_truth, density: float, after_cloud: np.ndarray,
                 capture_seed: int = 0, measured: bool = True) -> dict[str, float]:
    """Where the distance between simulation and truth comes from, for one twin datapoint ``dp`` prepared by
    the main pipeline, its fused after cloud ``after_cloud`` (n, 3) in m and its twin ``ground_truth``
    (:class:`dpsi.twin.GroundTruth`): height-map distances (mm) to the twin's true after surface, every map
    drawn on the truth's grid.

    The target's part: the captured, fused after cloud (``target``; ``measured``: it comes from cameras, so its
    map is drawn as the targets stage draws it, :func:`dpsi.prepare.target_heightmap`), and the true after
    surface captured again by the twin's cameras (seed ``capture_seed``) and fused, without calibration error
    (``target_no_calibration_error``) and also without depth noise (``target_exact_cameras``: what the
    cameras' sampling, the fusion and the smoothing leave). The simulation's part, at the truth on this ``simulator``:
    started from the twin's own particles (``twin_particles``: the simulator's resolution alone), from the
    true before shape filled at ``density`` particles/m³ (``true_shape_filled``: adds the particle density),
    and from the reconstructed before particles (``reconstructed``: adds the before shape's reconstruction;
    the pipeline)."""
    from dpsi.capture import Camera, capture  # open3d and pymeshlab
    from dpsi.prepare import target_heightmap
    from dpsi.reconstruction.filling import fill
    from dpsi.reconstruction.fusion import fuse
    from dpsi.twin import TABLE_Z, WORKSPACE, true_surface

    truth, true_hm, centre = ground_truth.parameters, ground_truth.heightmap, ground_truth.centre_xy
    spacing = ground_truth.particle_volume ** (1 / 3)
    true_after = true_surface(ground_truth.after_particles, spacing, name=f"{dp.id} true after")

    def cloud_distance(cloud: np.ndarray, from_cameras: bool) -> float:
        return heightmap_distance_mm(target_heightmap(cloud, centre, TABLE_Z, from_cameras), true_hm)

    def recaptured(**errors) -> float:
        views = capture(true_after, TABLE_Z, seed=capture_seed, **errors)
        return cloud_distance(fuse(views, *WORKSPACE, table_z=TABLE_Z), True)

    def simulated(particles: np.ndarray, volume: float) -> float:
        final = simulator.forward(dataclasses.replace(scene(dp), particles=particles, particle_volume=volume),
                                  truth, keep_substeps=False)
        drawn = dp.heightmap_target()._replace(heights=true_hm, centre_xy=centre, particle_size=volume ** (1 / 3))
        return heightmap_distance_mm(simulated_heightmap(final, drawn), true_hm)

    exact = {"translation_error": 0.0, "rotation_error": 0.0}
    true_shape = true_surface(ground_truth.before_particles, spacing, name=f"{dp.id} true before")
    return {"target": cloud_distance(after_cloud, measured),
            "target_no_calibration_error": recaptured(**exact),
            "target_exact_cameras": recaptured(**exact, camera=Camera(depth_noise=0.0)),
            "twin_particles": simulated(ground_truth.before_particles, ground_truth.particle_volume),
            "true_shape_filled": simulated(fill(true_shape, density), 1.0 / density),
            "reconstructed": simulated(dp.particles, dp.particle_volume)}


def loss_minima(simulator: Simulator, dp: Datapoint, truth: Parameters,
                losses: Sequence[str] = LADDER_LOSSES) -> pd.DataFrame:
    """One-parameter scans through ``truth`` (:data:`SCAN_PARAMETERS` at :data:`SCAN_FACTORS` times the truth,
    within their ranges) of each loss on ``dp``: per (parameter, loss) the value (SI) with the lowest loss, the
    loss (mm) there and at the truth, how much the loss varies over the scan (``loss_span_mm``, max − min), and
    how much the parameter changes the simulation itself (``signal_mm``: the mean height-map distance of the
    scan's simulations from the one at the truth). A loss whose minimum is not at the truth is biased on these
    data, whatever the optimiser does; a span far below the signal means the data hide what the parameter
    does."""
    rows = []
    data, drawn_as = targets(dp), dp.heightmap_target()
    for name in SCAN_PARAMETERS:
        true = getattr(truth, name)
        values = list(scan_values(name, true))
        finals = [simulator.forward(scene(dp), truth.replace(**{name: v}), keep_substeps=False) for v in values]
        maps = [simulated_heightmap(final, drawn_as) for final in finals]
        at_truth = values.index(true)
        signal = np.mean([heightmap_distance_mm(m, maps[at_truth]) for k, m in enumerate(maps) if k != at_truth])
        for loss in losses:
            scan = [loss_by_name(loss)(final, data)[0] for final in finals]
            best = int(np.argmin(scan))
            rows.append({"parameter": name, "loss": loss, "truth": true, "argmin": values[best],
                         "loss_at_argmin_mm": scan[best], "loss_at_truth_mm": scan[at_truth],
                         "loss_span_mm": max(scan) - min(scan), "signal_mm": float(signal)})
    return pd.DataFrame(rows)



__all__ = ["RUNGS", "LADDER_LOSSES", "COLUMNS", "SAME_AT_R0", "relabelled", "check_rung", "same_model_datapoint", "reconstructed_twin_datapoint",
           "level_truth", "reference", "run_rows", "RUN_LABELS", "ladder_table", "recovery_summary", "SCAN_PARAMETERS", "SCAN_FACTORS", "scan_values", "bias_sources", "loss_minima"]
