"""The baselines that identified parameters are compared with on a datapoint (:mod:`dpsi.generalisation`):
the hand-picked literature values as a run's level uses them, and no motion at all; and the metrics of a
run's parameters on the datapoints it did not train on. Distances in mm."""

from __future__ import annotations

import math
from collections.abc import Sequence

from dpsi.datapoint import Datapoint
from dpsi.identification import METRICS, evaluate
from dpsi.parameters import Parameters, hand_picked
from dpsi.simulation import SimulationError, Simulator


def metrics_or_nan(simulator: Simulator, dp: Datapoint, params: Parameters) -> dict[str, float]:
    """The validation metrics (mm) of ``dp`` simulated with ``params``; NaN for each if the simulation fails."""
    try:
        return evaluate(simulator, dp, params)
    except SimulationError:
        return dict.fromkeys(METRICS, math.nan)


def baseline(simulator: Simulator, dp: Datapoint, level: int) -> dict:
    """The two baselines of ``dp`` for runs of ``level``: its metrics (mm) with the hand-picked values
    (:func:`dpsi.parameters.hand_picked`) and with no motion."""
    return {"id": dp.id, "level": level, "hand_picked": metrics_or_nan(simulator, dp, hand_picked(level)),
            "no_motion": evaluate(simulator, dp, hand_picked(level), final=dp.particles)}


def on_unseen(simulator: Simulator, datapoints: Sequence[Datapoint], params: Parameters) -> list[dict]:
    """Per datapoint, the metrics (mm) of ``params``."""
    return [{"id": dp.id, **metrics_or_nan(simulator, dp, params)} for dp in datapoints]


__all__ = ["metrics_or_nan", "baseline", "on_unseen"]
