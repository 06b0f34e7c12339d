"""Do identified parameters predict data they were not identified on? The comparison of a run with the
baselines on its unseen datapoints, and the rule that recommends one set of parameters per level.

A run's *unseen* datapoints are the clay datapoints (of either level) outside its training set. On each
of them the run's selected parameters are compared with two baselines (:mod:`dpsi.baselines`): the
hand-picked literature values as the run's level uses them, and no motion at all. Distances are the
validation metrics of SPEC §6, in mm; the height map decides.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

DECIDING_METRIC = "heightmap_mm"
"""The validation metric that compares parameter sets (SPEC §6 chooses the best iteration by it)."""


def comparison_rows(summary: Mapping, unseen: Sequence[Mapping], baselines: Mapping[tuple[int, str], Mapping]) -> list[dict]:
    """One row per unseen datapoint of a run (``summary`` with its labels): its height-map distance (mm)
    with the run's parameters, the hand-picked values and no motion, and the relative change against the
    hand-picked values (negative: the identified parameters are closer)."""
    labels = summary["labels"]
    rows = []
    for record in unseen:
        base = baselines[(int(labels["level"]), record["id"])]
        identified, hand = record[DECIDING_METRIC], base["hand_picked"][DECIDING_METRIC]
        rows.append({"level": int(labels["level"]), "loss": labels["loss"], "dataset": labels["dataset"],
                     "seed": int(labels["seed"]), "pair": record["id"], "identified_mm": identified,
                     "hand_picked_mm": hand, "no_motion_mm": base["no_motion"][DECIDING_METRIC],
                     "change": (identified - hand) / hand})
    return rows


def worst_change(rows: Sequence[Mapping]) -> float:
    """The largest relative change against the hand-picked values over a run's unseen rows (NaN counts as
    worse than anything: a failed simulation is no prediction)."""
    changes = [r["change"] for r in rows]
    return math.inf if not changes or any(math.isnan(c) for c in changes) else max(changes)


def recommend(rows: Sequence[Mapping]) -> dict[int, tuple[str, str, int]]:
    """Per level, the (loss, dataset, seed) of the run to recommend: the lowest worst change against the
    hand-picked values over its unseen datapoints (the run least likely to predict a new pair worse than the
    literature values), ties broken by the mean change. Runs without unseen rows are not candidates."""
    runs: dict[tuple, list] = {}
    for r in rows:
        runs.setdefault((r["level"], r["loss"], r["dataset"], r["seed"]), []).append(r)
    best: dict[int, tuple] = {}
    for (level, loss, dataset, seed), run_rows in runs.items():
        score = (worst_change(run_rows), float(np.mean([r["change"] for r in run_rows])))
        if level not in best or score < best[level][0]:
            best[level] = (score, (loss, dataset, seed))
    return {level: choice for level, (_, choice) in sorted(best.items())}


__all__ = ["DECIDING_METRIC", "comparison_rows", "worst_change", "recommend"]
