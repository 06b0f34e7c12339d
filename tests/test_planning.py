"""Greedy planning towards a target height map (SPEC §7.8): the candidates' geometry, the search on a
small scene whose target one known candidate produces, and the workflow's plan table and figure."""

import json
import math

import numpy as np
import pandas as pd
import pytest

from dpsi import effectors
from dpsi.heightmap import height_map, heightmap_distance_mm
from dpsi.losses import HeightMapTarget
from dpsi.parameters import HAND_PICKED
from dpsi.planning import (EMPTY_ACTION, ActionSet, Planner, candidates, load_plan, save_plan,
                           start_locations)
from dpsi.simulation import Simulator, SimulatorConfig

SPACING = 0.004  # m between particles: a coarse object keeps the simulations fast
CENTRE = np.array([0.01, -0.02])  # m, off the origin so that centring is checked
CONFIG = SimulatorConfig(width=0.12, height=0.08, max_particles=1500, max_steps=120)
"""As in test_simulation.py, so that the compiled kernels are shared through Taichi's cache."""


def block(size=(0.03, 0.03, 0.02)):
    """Particles filling a box standing on the table z = 0, its footprint centred at CENTRE."""
    axes = [(np.arange(round(s / SPACING)) - (round(s / SPACING) - 1) / 2) * SPACING + c
            for s, c in zip(size[:2], CENTRE)]
    axes.append(np.arange(SPACING / 2, size[2], SPACING))
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


@pytest.fixture(scope="module")
def simulator():
    return Simulator(CONFIG)


def planner(simulator, motions=("poking-2",), grid=2, spacing=0.015):
    return Planner(simulator, HAND_PICKED, ActionSet(motions, effectors.ROUND, grid, spacing), SPACING ** 3, 0.0)


def target_of(particles):
    """The height map of ``particles`` as a target centred at CENTRE."""
    return HeightMapTarget(height_map(particles, CENTRE), CENTRE, 0.0)


# ---------------------------------------------------------------- candidates
def test_start_locations_are_a_grid_centred_on_the_footprint_at_the_top():
    particles = block()
    starts = start_locations(particles, 3, 0.03)
    assert starts.shape == (9, 3)
    assert starts[:, :2].mean(axis=0) == pytest.approx(CENTRE)
    assert np.all(starts[:, 2] == particles[:, 2].max())
    for k in range(2):
        assert np.unique(starts[:, k].round(9)) == pytest.approx(CENTRE[k] + np.array([-0.03, 0.0, 0.03]))
    gaps = np.linalg.norm(starts[:, None, :2] - starts[None, :, :2], axis=-1)
    assert gaps[gaps > 0].min() == pytest.approx(0.03)


def test_candidates_are_the_empty_action_then_every_motion_at_every_location():
    particles = block()
    options = candidates(particles, ActionSet(("poking-shifting-1", "poking-shifting-2"), effectors.ROUND))
    assert len(options) == 19 and options[0] == EMPTY_ACTION
    assert [a.motion for a in options[1:]] == ["poking-shifting-1"] * 9 + ["poking-shifting-2"] * 9
    assert len({a.start for a in options[1:]}) == 9


# ---------------------------------------------------------------- search
def test_one_action_plan_finds_the_candidate_that_made_the_target(simulator):
    """The target is the outcome of one candidate: the greedy step must pick it, reaching distance 0."""
    start = block()
    search = planner(simulator)
    known = candidates(start, search.actions)[3]
    target = target_of(search.outcome(start, known))
    plan = search.plan(start, target, 1)
    assert plan.initial_distance_mm > 100.0  # the poke is visible in the height map
    assert plan.steps[0].action == known
    assert plan.final_distance_mm == pytest.approx(0.0, abs=1e-9)
    assert plan.steps[0].tried == 5 and not plan.steps[0].skipped


def test_the_empty_action_wins_when_the_start_is_the_target(simulator):
    start = block()
    plan = planner(simulator).plan(start, target_of(start), 2)
    assert [s.action for s in plan.steps] == [EMPTY_ACTION] * 2
    assert plan.initial_distance_mm == plan.final_distance_mm == 0.0
    assert np.array_equal(plan.steps[-1].particles, start)


def test_candidates_leaving_the_simulated_box_are_skipped_and_recorded(simulator, tmp_path):
    """0.04 m from the centre the tip is outside the 0.12 m box (less its margins): only the middle
    location and the empty action can run. The plan survives a save and load."""
    start = block()
    plan = planner(simulator, grid=3, spacing=0.04).plan(start, target_of(block((0.03, 0.03, 0.012))), 1)
    step = plan.steps[0]
    assert step.tried == 10 and len(step.skipped) == 8
    assert all("leaves the simulated box" in reason for _, reason in step.skipped)
    assert all(np.abs(np.subtract(a.start[:2], CENTRE)).max() == pytest.approx(0.04) for a, _ in step.skipped)
    assert step.distance_mm <= plan.initial_distance_mm
    save_plan(tmp_path / "plan.json", tmp_path / "plan.npz", plan, note="test")
    loaded, record = load_plan(tmp_path / "plan.json", tmp_path / "plan.npz")
    assert record["note"] == "test" and loaded.steps[0].action == step.action
    assert loaded.steps[0].skipped == step.skipped
    assert np.array_equal(loaded.steps[0].heightmap, step.heightmap)
    assert loaded.final_distance_mm == heightmap_distance_mm(step.heightmap, loaded.target.heights)


# ---------------------------------------------------------------- workflow
def test_workflow_plan_lowers_the_distance_to_its_target(tiny_run):
    tables, figures = tiny_run / "results" / "twin-tiny" / "tables", tiny_run / "results" / "twin-tiny" / "figures"
    outputs = [tables / f"planning.{s}" for s in ("csv", "md", "tex")]
    for path in outputs + [figures / f"planning.{s}" for s in ("png", "pdf")]:
        assert path.stat().st_size > 0, path
    table = pd.read_csv(tables / "planning.csv")
    record = json.loads(next((tiny_run / "results").glob("*/planning/plan.json")).read_text())
    assert len(table) == len(record["actions"]) + 1
    distances = table["heightmap_mm"].to_numpy()
    assert np.isfinite(distances).all()
    assert distances[-1] <= distances[0] and np.all(np.diff(distances) <= 0)
    assert math.isclose(distances[-1], record["final_distance_mm"])
