"""The identifiability ladder: R0 (same model) on the tiny poked block of test_identification, and the
ladder table."""

import dataclasses
import io

import numpy as np
import pandas as pd
import pytest

from conftest import assert_same_numbers
from dpsi.datapoint import Datapoint
from dpsi.effectors import by_name
from dpsi.heightmap import height_map, heightmap_distance_mm
from dpsi.identifiability import (COLUMNS, LADDER_LOSSES, SAME_AT_R0, SCAN_PARAMETERS, bias_sources, ladder_table,
                                  loss_minima, recovery_summary, reference, relabelled, same_model_datapoint)
from dpsi.identification import identify, scene
from dpsi.losses import simulated_heightmap
from dpsi.parameters import IDENTIFIED, SCALE_FREE
from dpsi.prepare import surface_points
from dpsi.reporting import figures
from dpsi.simulation import Simulator
from dpsi.twin import CENTRE, GroundTruth, true_surface
from test_identification import CONFIG, SPACING, TRUTH, block, poke


def untargeted(effector: str, depth: float) -> Datapoint:
    """The block poked by ``effector``, with placeholder targets."""
    particles = block()
    centre = particles[:, :2].mean(axis=0)
    start = np.array([*centre, particles[:, 2].max() + SPACING / 2])
    return Datapoint(effector, "poke", by_name(effector), particles, SPACING**3, poke(depth), start, 0.0,
                     particles, particles, np.zeros((32, 32)), centre)


@pytest.fixture(scope="module")
def rung0():
    """(simulator, training, validation) at R0."""
    simulator = Simulator(CONFIG)
    same = [same_model_datapoint(untargeted(e, d), simulator, TRUTH)
            for e, d in (("round", 0.008), ("rectangle", 0.008), ("cylinder", 0.006))]
    return simulator, same[:2], same[2:]


def test_every_loss_is_zero_at_the_truth_on_rung_0(rung0):
    simulator, training, validation = rung0
    ref = reference(simulator, training, validation, TRUTH, level=1)
    assert set(ref["loss_at_truth_mm"]) == set(LADDER_LOSSES)
    assert all(value == pytest.approx(0.0, abs=1e-9) for value in ref["loss_at_truth_mm"].values())
    assert ref["val_heightmap_truth_mm"] == pytest.approx(0.0, abs=1e-9)
    # the poke moves the block: doing nothing, or the hand-picked material, is measurably off
    assert ref["val_heightmap_no_motion_mm"] > 20.0 and ref["val_heightmap_hand_picked_mm"] > 5.0


def test_on_rung_0_every_loss_has_its_minimum_at_the_truth(rung0):
    simulator, training, _ = rung0
    minima = loss_minima(simulator, training[0], TRUTH)
    assert len(minima) == len(SCAN_PARAMETERS) * len(LADDER_LOSSES)
    assert (minima.argmin == minima.truth).all(), minima
    assert (minima.loss_at_truth_mm < 1e-9).all()
    # at R0 the height-map loss is the distance to the truth's map: its span over the scan is at least the
    # mean distance of the scan's simulations from the truth's, the signal
    assert (minima.signal_mm > 1.0).all()
    height = minima[minima.loss == "heightmap"]
    assert (height.loss_span_mm >= height.signal_mm - 1e-9).all()


@pytest.mark.parametrize("loss", ["prt_emd", "pcd_cd"])
def test_rung_0_recovers_young_modulus_and_yield_stress_from_50_percent_off(rung0, loss, tmp_path):
    simulator, training, validation = rung0
    start = TRUTH.replace(E=0.5 * TRUTH.E, yield_stress=1.5 * TRUTH.yield_stress)
    summary = identify(tmp_path, 1, loss, training, validation, iterations=30, initial=start, truth=TRUTH,
                       simulator=simulator, progress=io.StringIO())
    assert summary["relative_error"]["E"] < 0.10
    assert summary["relative_error"]["yield_stress"] < 0.10


def test_on_rung_0_each_pcd_loss_runs_exactly_as_its_prt_loss_so_its_run_is_relabelled(rung0, tmp_path):
    simulator, training, validation = rung0
    start = TRUTH.replace(E=0.5 * TRUTH.E, yield_stress=1.5 * TRUTH.yield_stress)
    labels = dict(rung="R0", level=1, dataset="1-round", seed=0)
    summaries, logs = {}, {}
    for pcd, prt in SAME_AT_R0.items():
        for loss in (pcd, prt):
            summaries[loss] = identify(tmp_path / loss, 1, loss, training, validation, iterations=2, initial=start,
                                       truth=TRUTH, simulator=simulator, progress=io.StringIO(),
                                       labels={**labels, "loss": loss})
            logs[loss] = pd.read_csv(tmp_path / loss / "log.csv").drop(columns="wall_s")
        # the same numbers up to the order of the simulator's parallel sums (the last bit of a gradient)
        pd.testing.assert_frame_equal(logs[pcd], logs[prt], check_exact=False, rtol=1e-12, atol=1e-12)
        assert logs[prt].train_loss_mm.iloc[0] > 1.0  # the runs start off the truth and move
        stand_in = relabelled(summaries[prt], pcd)
        assert stand_in["loss"] == stand_in["labels"]["loss"] == pcd and stand_in["same_run_as"] == prt
        unlabelled = ("loss", "labels", "same_run_as", "wall_s")
        assert {k: v for k, v in stand_in.items() if k not in unlabelled} == \
               {k: v for k, v in summaries[prt].items() if k not in unlabelled}
        assert_same_numbers({k: v for k, v in summaries[pcd].items() if k not in unlabelled},
                            {k: v for k, v in summaries[prt].items() if k not in unlabelled})
    with pytest.raises(ValueError, match="only an R0 run of 'prt_emd'"):
        relabelled(summaries["prt_cd"], "pcd_emd")
    with pytest.raises(ValueError, match="this is a R1 run"):
        relabelled({**summaries["prt_cd"], "labels": {**labels, "rung": "R1", "loss": "prt_cd"}}, "pcd_cd")


def test_bias_sources_draw_every_map_on_the_truth_s_grid():
    simulator = Simulator(CONFIG)
    dp = untargeted("round", 0.008)
    dp = dataclasses.replace(dp, particles=dp.particles + [*CENTRE, 0.0], start=dp.start + [*CENTRE, 0.0],
                             centre_xy=dp.centre_xy + CENTRE)
    after = simulator.forward(scene(dp), TRUTH, keep_substeps=False)
    true_cloud = surface_points(true_surface(after, SPACING))
    true_map = height_map(true_cloud, dp.centre_xy, floor=0.0)
    truth = GroundTruth("block", "clay", TRUTH, SPACING**3, 0.0, dp.particles, after, dp.centre_xy, true_map)
    pipeline = dataclasses.replace(dp, centre_xy=dp.centre_xy + [0.002, 0.0])  # its maps' grid is off the truth's
    sources = bias_sources(simulator, pipeline, truth, 1.0 / SPACING**3, true_cloud, measured=False)
    assert sources["target"] == 0.0  # the true surface's own cloud, drawn on the truth's grid
    # the same simulator from the twin's own particles repeats the twin: what is left is drawing the particles
    # as cubes instead of their wrapped surface
    drawn = dp.heightmap_target()._replace(heights=true_map, particle_size=SPACING)
    assert sources["twin_particles"] == pytest.approx(heightmap_distance_mm(simulated_heightmap(after, drawn), true_map))
    # recaptures without calibration error are closer to the moved block than the unmoved block is (on this
    # tiny block the smoothing's rounded edges are most of what is left: 73 and 101 mm against 190)
    unmoved = heightmap_distance_mm(simulated_heightmap(dp.particles, drawn), true_map)
    assert 0.0 < sources["target_no_calibration_error"] < 0.6 * unmoved
    assert 0.0 < sources["target_exact_cameras"] < 0.6 * unmoved


def fake_run(seed, estimate, loss_at_best, known=(), rung="R0", dataset="1-round"):
    labels = dict(rung=rung, level=1, loss="prt_emd", dataset=dataset, seed=seed)
    summary = {**labels, "known": sorted(known),
               "best": {"iteration": 2, "parameters": estimate, "validation": {"heightmap_mm": 100.0}}}
    log = pd.DataFrame({"iteration": [0, 1, 2], "train_loss_mm": [900.0, 500.0, loss_at_best]}).assign(**labels)
    return summary, log


def test_ladder_table_has_a_row_per_identified_parameter_with_relative_errors():
    truth = TRUTH.as_dict()
    ref = {"truth": truth, "loss_at_truth_mm": {"prt_emd": 0.0}, "val_heightmap_hand_picked_mm": 300.0,
           "val_heightmap_no_motion_mm": 900.0}
    runs = [fake_run(s, {**truth, "E": truth["E"] * (1 + 0.1 * (s + 1))}, 40.0 + s) for s in (1, 0)]
    table = ladder_table([s for s, _ in runs], pd.concat([log for _, log in runs]), {("R0", 1, "1-round"): ref})
    per_run = len(IDENTIFIED[1]) + len(SCALE_FREE)
    assert list(table.columns) == list(COLUMNS) and len(table) == 2 * per_run
    assert list(table.seed) == [0] * per_run + [1] * per_run
    e = table[table.parameter == "E"].set_index("seed")
    assert e.rel_error.to_dict() == pytest.approx({0: 0.1, 1: 0.2})
    assert e.loss_at_estimate_mm.to_dict() == {0: 40.0, 1: 41.0}
    # E off by 10 % puts E/ρ off by 10 % and the yield strain σ_y/E off by 1 − 1/1.1
    ratios = table[table.seed == 0].set_index("parameter").rel_error
    assert ratios["E/rho"] == pytest.approx(0.1) and ratios["yield_stress/E"] == pytest.approx(1 - 1 / 1.1)
    assert (table.loc[~table.parameter.isin(["E", *SCALE_FREE]), "rel_error"] == 0).all()
    assert recovery_summary(table).loc[("R0", 1, "1-round", "prt_emd"), "E"] == pytest.approx(0.15)


def test_the_recovery_figure_draws_each_dataset_of_each_rung_in_a_panel_of_its_own(tmp_path, monkeypatch):
    truth = TRUTH.as_dict()
    ref = {"truth": truth, "loss_at_truth_mm": {"prt_emd": 0.0}, "val_heightmap_hand_picked_mm": 300.0,
           "val_heightmap_no_motion_mm": 900.0}
    e_factor = {("R0", "1-round"): 1.05, ("R2", "1-round"): 1.3, ("R2", "ood"): 1.1}
    runs = [fake_run(0, {**truth, "E": truth["E"] * f}, 40.0, rung=r, dataset=d) for (r, d), f in e_factor.items()]
    table = ladder_table([s for s, _ in runs], pd.concat([log for _, log in runs]),
                         {(r, 1, d): ref for r, d in e_factor})
    drawn = {}
    monkeypatch.setattr(figures, "save", lambda fig, png, pdf: drawn.update(fig=fig))
    figures.plot_recovery(table, tmp_path / "f.png", tmp_path / "f.pdf")
    panels = {ax.get_title(): ax for ax in drawn["fig"].axes if ax.get_visible()}
    assert set(panels) == {"level 1, 1-round, R0", "level 1, 1-round, R2", "level 1, ood, R2"}
    assert len(drawn["fig"].axes) == 4  # the empty (ood, R0) panel is hidden, title and all
    for (rung, dataset), factor in e_factor.items():
        bars = panels[f"level 1, {dataset}, {rung}"].patches
        assert bars[0].get_height() == pytest.approx(100 * (factor - 1))  # E, the first parameter


def test_a_parameter_held_known_gets_no_row_but_its_value_enters_the_ratios():
    truth = TRUTH.as_dict()
    ref = {"truth": truth, "loss_at_truth_mm": {"prt_emd": 0.0}, "val_heightmap_hand_picked_mm": 300.0,
           "val_heightmap_no_motion_mm": 900.0}
    summary, log = fake_run(0, {**truth, "E": truth["E"] * 1.2}, 40.0, known=["rho"])
    table = ladder_table([summary], log, {("R0", 1, "1-round"): ref}).set_index("parameter")
    assert "rho" not in table.index and len(table) == len(IDENTIFIED[1]) - 1 + len(SCALE_FREE)
    assert table.rel_error["E/rho"] == pytest.approx(0.2)
