"""Comparing identified parameters with the baselines on unseen datapoints, and the recommendation rule."""

import math

import pytest

from dpsi.generalisation import comparison_rows, recommend, worst_change


def _baseline(hand, still):
    return {"hand_picked": {"heightmap_mm": hand}, "no_motion": {"heightmap_mm": still}}


def test_each_unseen_datapoint_is_compared_with_its_baselines_at_the_runs_level():
    baselines = {(1, "a"): _baseline(500.0, 900.0), (2, "a"): _baseline(400.0, 900.0), (1, "b"): _baseline(200.0, 300.0)}
    summary = {"labels": {"level": 1, "loss": "heightmap", "dataset": "pair-c", "seed": 0}}
    rows = comparison_rows(summary, [{"id": "a", "heightmap_mm": 450.0}, {"id": "b", "heightmap_mm": 220.0}], baselines)
    assert [(r["pair"], r["hand_picked_mm"], r["no_motion_mm"]) for r in rows] == [("a", 500.0, 900.0), ("b", 200.0, 300.0)]
    assert [r["change"] for r in rows] == pytest.approx([-0.1, 0.1])


def _rows(level, dataset, changes):
    return [{"level": level, "loss": "heightmap", "dataset": dataset, "seed": 0, "change": c} for c in changes]


def test_the_recommended_run_is_the_one_whose_worst_unseen_change_is_lowest():
    rows = (_rows(1, "pair-a", [-0.30, 0.05]) + _rows(1, "pair-b", [-0.02, -0.01]) + _rows(1, "mix", [-0.10, 0.02])
            + _rows(2, "pair-c", [0.01]) + _rows(2, "pair-d", [math.nan, -0.5]))
    assert recommend(rows) == {1: ("heightmap", "pair-b", 0), 2: ("heightmap", "pair-c", 0)}
    assert worst_change(_rows(2, "pair-d", [math.nan, -0.5])) == math.inf


def test_ties_in_the_worst_change_go_to_the_lower_mean():
    rows = _rows(1, "pair-a", [0.0, 0.0]) + _rows(1, "pair-b", [0.0, -0.2])
    assert recommend(rows) == {1: ("heightmap", "pair-b", 0)}
