"""Identification on the real clay pairs (dpsi.real_clay): datapoints, alignment, distances, one iteration."""

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

import dpsi.real_clay
from dpsi.heightmap import height_map, heightmap_distance_mm
from dpsi.identifiability_landscape import PAIR
from dpsi.landscapes import Landscape
from dpsi.parameters import HAND_PICKED, LEVEL1_FIXED, Parameters
from dpsi.prepare import surface_points
from dpsi.real_clay import (
    GRID,
    PAIRS,
    comparison_rows,
    grid_report,
    identify_on_real,
    main,
    pair_meshes,
    real_datapoint,
    simulated_mm,
    table_aligned,
)
from dpsi.simulation import Simulator, SimulatorConfig

REAL_CLAY = Path(__file__).resolve().parents[1].parent / "shared" / "real-clay"
needs_real_clay = pytest.mark.skipif(not REAL_CLAY.is_dir(), reason=f"real clay meshes not found at {REAL_CLAY}")


def test_table_aligned_puts_both_on_the_table_with_common_footprint_centre():
    before = o3d.geometry.TriangleMesh.create_box(0.06, 0.04, 0.03).translate([-0.03, -0.02, -0.015])
    after = o3d.geometry.TriangleMesh.create_box(0.07, 0.05, 0.02).translate([0.1, 0.2, -0.3])
    b, a = table_aligned(before, after)
    assert b.get_min_bound()[2] == pytest.approx(0.0, abs=1e-12)
    assert a.get_min_bound()[2] == pytest.approx(0.0, abs=1e-12)
    centre = lambda m: (m.get_min_bound()[:2] + m.get_max_bound()[:2]) / 2
    np.testing.assert_allclose(centre(a), centre(b), atol=1e-12)
    np.testing.assert_allclose(centre(b), [0.0, 0.0], atol=1e-12)
    assert b.get_max_bound()[2] == pytest.approx(0.03) and a.get_max_bound()[2] == pytest.approx(0.02)


@needs_real_clay
@pytest.mark.parametrize("name", sorted(PAIRS))
def test_real_datapoint_fills_the_before_mesh_and_starts_on_its_top(name):
    before, after = pair_meshes(REAL_CLAY, name)
    dp = real_datapoint(REAL_CLAY, name, 2e7)
    assert dp.effector.name == PAIRS[name].effector and dp.motion == "poking-1"
    # particles lie inside the before shape: on the table, under its top surface, in its footprint
    assert dp.particles[:, 2].min() >= -1e-9
    top = height_map(surface_points(before), dp.centre_xy)
    filled = height_map(dp.particles, dp.centre_xy)
    assert (filled <= top + 0.001).all()  # surface samples 1 mm apart miss a cell's top by up to 0.7 mm
    assert (filled > 0).sum() > 0.6 * (top > 0.002).sum()
    # the fill lattice leaves a half-spacing skin and cell maxima overestimate: measured 0.64-0.84
    assert 0.5 < len(dp.particles) / (2e7 * _top_volume(top)) < 1.0
    # the tip starts at the top centre of the before mesh; the targets are the after mesh's
    lo, hi = before.get_min_bound(), before.get_max_bound()
    np.testing.assert_allclose(dp.start, [*(lo[:2] + hi[:2]) / 2, hi[2]], atol=1e-9)
    assert dp.heightmap.max() == pytest.approx(after.get_max_bound()[2], abs=2e-3)
    assert dp.heightmap.min() >= -1e-9
    # the motion presses the top down: the after top is lower than the before top
    assert dp.heightmap.max() < top.max() - 0.003


def _top_volume(heights):
    """Volume (m³) under a 32 × 32 height map of the 0.11 m square."""
    return float(heights.sum() * (0.11 / 32) ** 2)


@needs_real_clay
def test_one_identification_iteration_on_a_real_pair(tmp_path):
    simulator = Simulator(SimulatorConfig())
    summary, rows = identify_on_real(REAL_CLAY, "cylinder-5", tmp_path, iterations=1, density=2e7,
                                     loss="prt_emd", simulator=simulator)
    assert summary["completed_iterations"] == 1 and summary["best"]["iteration"] == 1
    identified = Parameters.checked(**summary["best"]["parameters"])
    assert identified != HAND_PICKED.replace(**LEVEL1_FIXED)  # one Adam step moved θ
    assert (identified.mu_table, identified.mu_effector) == (LEVEL1_FIXED["mu_table"], LEVEL1_FIXED["mu_effector"])
    assert [(r["pair"], r["role"]) for r in rows] == [("cylinder-5", "training"), ("rectangle-8", "unseen"),
                                                      ("round-2", "unseen")]
    assert rows[0]["identified_mm"] == pytest.approx(summary["best"]["validation"]["heightmap_mm"])
    for row in rows:
        dp = real_datapoint(REAL_CLAY, row["pair"], 2e7)
        before_mm = heightmap_distance_mm(height_map(dp.particles, dp.centre_xy, floor=0.0,
                                                     particle_size=dp.particle_size), dp.heightmap)
        assert row["unmoved_mm"] == pytest.approx(before_mm)
        assert row["change"] == pytest.approx((row["identified_mm"] - row["hand_picked_mm"]) / row["hand_picked_mm"])
        # simulating the poke brings the shape closer to the real after state than not moving it
        assert 0 < row["hand_picked_mm"] < row["unmoved_mm"]
    # the hand-picked distance is that of a simulation with the hand-picked values, not the identified ones
    same = comparison_rows(simulator, [real_datapoint(REAL_CLAY, "rectangle-8", 2e7)],
                           HAND_PICKED.replace(**LEVEL1_FIXED), HAND_PICKED.replace(**LEVEL1_FIXED))[0]
    assert same["identified_mm"] == pytest.approx(rows[1]["hand_picked_mm"]) and same["change"] == 0


def test_grid_report_lists_the_cells_closer_than_the_hand_picked_values_on_every_pair():
    e, s = np.array(GRID["E"]), np.array(GRID["yield_stress"])
    hand = (list(e).index(HAND_PICKED.E), list(s).index(HAND_PICKED.yield_stress))
    first, second = np.full((len(e), len(s)), 500.0), np.full((len(e), len(s)), 600.0)
    first[hand], second[hand] = 400.0, 450.0
    first[3, 1], second[3, 1] = 300.0, 440.0  # closer on both pairs
    first[4, 4], second[4, 4] = 350.0, 460.0  # closer on the first only
    landscapes = {name: Landscape(PAIR, ("heightmap",), e, s, values[None], HAND_PICKED.replace(**LEVEL1_FIXED))
                  for name, values in (("p", first), ("q", second))}
    text = grid_report(landscapes)
    assert "| p | 400 | 300 | 60, 1.5 | -25.0 % |" in text and "| q | 450 | 440 | 60, 1.5 | -2.2 % |" in text
    assert text.endswith("on every pair: (60, 1.5).\n")
    first[3, 1] = 401.0
    assert grid_report(landscapes).endswith("on every pair: none.\n")


@needs_real_clay
def test_grid_command_reports_every_pair_at_the_hand_picked_values(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(dpsi.real_clay, "GRID", {"E": (HAND_PICKED.E, 2 * HAND_PICKED.E),
                                                 "yield_stress": (HAND_PICKED.yield_stress, 2 * HAND_PICKED.yield_stress)})
    assert main(["--shared", str(REAL_CLAY), "--grid", "--density", "2e7", "--out", str(tmp_path / "g.md")]) == 0
    text = (tmp_path / "g.md").read_text()
    assert text in capsys.readouterr().out  # printed as well
    simulator = Simulator(SimulatorConfig())
    for name in PAIRS:
        hand = simulated_mm(simulator, real_datapoint(REAL_CLAY, name, 2e7), HAND_PICKED.replace(**LEVEL1_FIXED))
        assert f"| {name} | {hand:.0f} |" in text
