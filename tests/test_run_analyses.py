"""The analyses that are variations of identification runs (SPEC §7.4 other materials, §7.5 local
minima, §7.7 appendix A): their table builders on made-up run summaries, loading runs, their figures,
and the tiny end-to-end workflow's tables and figures."""

import json
import math

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import TINY, snakemake

from dpsi.parameters import HAND_PICKED, IDENTIFIED, NAMES
from dpsi.reporting.figures import plot_runs
from dpsi.reporting.runs import load_runs
from dpsi.reporting.tables import (ANY_SEED_LABEL, heightmap_losses_table, materials_table, minima_table,
                                   write_table)
from dpsi.twin_plan import MATERIALS
from test_figures import assert_figure, synthetic_runs


def summary(seed, heightmap_mm, scale=1.0, **labels):
    """A made-up run summary whose best iteration (seed + 1) has the hand-picked parameters times
    ``scale`` and validation metrics heightmap_mm, and 10, 20, 30, 40 mm for the point-cloud metrics."""
    return {"seed": seed, "level": labels.pop("level", 1), **labels,
            "best": {"iteration": seed + 1,
                     "parameters": {n: getattr(HAND_PICKED, n) * scale for n in NAMES},
                     "validation": {"pcd_cd": 10.0, "prt_cd": 20.0, "pcd_emd": 30.0, "prt_emd": 40.0,
                                    "heightmap_mm": heightmap_mm}}}


TRUTHS = {"slime": MATERIALS["slime"].as_dict(), "soil": MATERIALS["soil"].as_dict()}


def test_materials_table_takes_the_best_seed_and_its_relative_error():
    runs = [summary(0, 900.0, 1.1, material="slime"), summary(1, 800.0, 1.5, material="slime"),
            summary(0, 700.0, 0.5, material="soil"), {"seed": 1, "material": "soil", "best": None}]
    table = materials_table(runs, {"slime": {n: getattr(HAND_PICKED, n) for n in NAMES}, "soil": TRUTHS["soil"]})
    assert list(table.columns) == ["material", "parameter", "truth", "seed0", "seed1", "estimate", "rel_error",
                                   "val_heightmap_mm"]
    assert list(table.groupby("material").size()) == [6, 6]
    slime = table[table.material == "slime"].set_index("parameter")
    assert slime.rel_error.to_numpy() == pytest.approx(np.full(6, 0.5))  # seed 1 is best: 1.5 × truth
    assert slime.loc["E", "seed0"] == pytest.approx(1.1 * HAND_PICKED.E)
    assert (slime.val_heightmap_mm == 800.0).all()
    soil = table[table.material == "soil"].set_index("parameter")
    assert soil.seed1.isna().all() and (soil.val_heightmap_mm == 700.0).all()
    expected = abs(0.5 * HAND_PICKED.rho - TRUTHS["soil"]["rho"]) / TRUTHS["soil"]["rho"]
    assert soil.loc["rho", "rel_error"] == pytest.approx(expected)


def test_minima_table_has_a_row_per_random_seed_and_one_hand_picked_row():
    runs = [summary(s, 1000.0 + s, dataset=d, start="random") for d in ("1-round", "1-cylinder") for s in (4, 3)]
    runs += [summary(3, 500.0, dataset=d, start="hand-picked") for d in ("1-round", "1-cylinder")]
    table = minima_table(runs)
    assert list(table.columns) == ["dataset", "start", "seed", "best_iteration", "val_heightmap_mm",
                                   *IDENTIFIED[1]]
    assert list(table.dataset) == ["1-cylinder"] * 3 + ["1-round"] * 3
    assert list(table.start) == ["random", "random", "hand-picked"] * 2
    assert list(table.seed) == [3, 4, ANY_SEED_LABEL] * 2
    assert list(table.val_heightmap_mm) == [1003.0, 1004.0, 500.0] * 2
    assert (table.E == HAND_PICKED.E).all() and "mu_table" not in table


def test_heightmap_losses_table_picks_the_best_seed_and_averages_datasets():
    runs = [summary(0, 300.0, loss="heightmap", dataset="1-round"),
            summary(1, 200.0, loss="heightmap", dataset="1-round"),
            summary(0, 400.0, loss="heightmap", dataset="6-mix"),
            summary(0, 900.0, loss="neg_heightmap", dataset="1-round"),
            {"seed": 1, "loss": "neg_heightmap", "dataset": "6-mix", "best": None}]
    table = heightmap_losses_table(runs).set_index(["loss", "dataset"])
    assert list(table.columns) == ["seed", "best_iteration", "val_pcd_cd", "val_prt_cd", "val_pcd_emd",
                                   "val_prt_emd", "val_heightmap_mm"]
    assert table.loc[("heightmap", "1-round"), "seed"] == 1
    assert table.loc[("heightmap", "average"), "val_heightmap_mm"] == pytest.approx(300.0)
    assert table.loc[("neg_heightmap", "average"), "val_heightmap_mm"] == pytest.approx(900.0)
    assert math.isnan(table.loc[("neg_heightmap", "6-mix"), "val_prt_cd"])
    assert table.loc[("heightmap", "6-mix"), "val_prt_emd"] == 40.0


def test_analysis_tables_are_written_in_three_formats(tmp_path):
    runs = [summary(0, 900.0, material="slime")]
    outputs = write_table(materials_table(runs, TRUTHS), tmp_path / "materials.csv", "Other materials")
    assert [p.suffix for p in outputs] == [".csv", ".md", ".tex"]
    assert pd.read_csv(outputs[0]).shape == (6, 7)


def test_load_runs_labels_summaries_and_log_rows(tmp_path):
    files = []
    for seed in (0, 1):
        folder = tmp_path / f"seed{seed}"
        folder.mkdir()
        labels = dict(level=2, loss="prt_emd", dataset="1-cylinder", seed=seed, start="random",
                      material=("slime", "soil")[seed])
        (folder / "summary.json").write_text(json.dumps({**summary(seed, 100.0, loss="prt_emd"), "labels": labels}))
        pd.DataFrame({"iteration": [0, 1, 2], "E": [1e4, 2e4, 3e4]}).to_csv(folder / "log.csv", index=False)
        files.append((folder / "summary.json", folder / "log.csv"))
    summaries, logs = load_runs(*zip(*files))
    assert [s["material"] for s in summaries] == ["slime", "soil"] and summaries[1]["loss"] == "prt_emd"
    assert len(logs) == 6 and list(logs.groupby("material").seed.first()) == [0, 1]
    assert set(logs.dataset) == {"1-cylinder"} and set(logs.start) == {"random"}
    with pytest.raises(ValueError, match="one of each per run"):
        load_runs([files[0][0]], [])
    (tmp_path / "old.json").write_text(json.dumps(summary(0, 100.0, loss="prt_emd")))
    with pytest.raises(ValueError, match="lacks the label"):
        load_runs([tmp_path / "old.json"], [files[0][1]])


def test_plot_runs_by_other_keys_with_truth(tmp_path):
    runs = synthetic_runs(levels=(2,)).rename(columns={"dataset": "material"})
    runs["material"] = runs["material"].map({"12-mix": "slime", "1-round": "soil"})
    plot_runs(runs, 2, tmp_path / "materials.png", tmp_path / "materials.pdf", columns="material", truth=TRUTHS,
              title="Other materials")
    assert_figure(tmp_path, "materials")
    with pytest.raises(ValueError, match="start"):
        plot_runs(runs, 2, tmp_path / "m.png", tmp_path / "m.pdf", colours="start")


def tiny_config(tmp_path, analysis, **changes):
    """tests/data/tiny.yaml with some settings of ``analysis`` changed, written into ``tmp_path``."""
    config = yaml.safe_load(TINY.read_text())
    config["analyses"][analysis].update(changes)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def test_an_analysis_reuses_the_runs_of_the_main_sweep(tmp_path):
    config = tiny_config(tmp_path, "heightmap_losses", losses=["prt_cd", "heightmap"])  # prt_cd: a main run
    run = snakemake(tmp_path, "-n", "heightmap_losses_results", config=config)
    assert run.returncode == 0, run.stderr
    assert "twin-tiny/runs/L1/prt_cd/1-round/seed0/summary.json" in run.stdout
    assert "heightmap_losses/clay/random/L1/heightmap/1-round/seed0/summary.json" in run.stdout
    assert "heightmap_losses/clay/random/L1/prt_cd" not in run.stdout


def test_a_material_without_datapoints_fails_at_start_up(tmp_path):
    run = snakemake(tmp_path, "-n", "tables", config=tiny_config(tmp_path, "materials", materials=["soil"]))
    assert run.returncode != 0
    output = run.stdout + run.stderr
    assert "analysis materials" in output and "poking-shifting-2 with cylinder (found 0)" in output


# ------------------------------------------------------------------ the tiny workflow (tests/data/tiny.yaml)
def test_tiny_materials_table(tiny_run):
    table = pd.read_csv(tiny_run / "results" / "twin-tiny" / "tables" / "materials.csv")
    assert list(table.columns) == ["material", "parameter", "truth", "seed0", "estimate", "rel_error",
                                   "val_heightmap_mm"]
    assert list(table.material) == ["slime"] * 6 and list(table.parameter) == list(NAMES)
    assert list(table.truth) == pytest.approx([getattr(MATERIALS["slime"], n) for n in NAMES])
    assert np.isfinite(table[["truth", "estimate", "rel_error", "val_heightmap_mm"]]).all().all()
    assert table.rel_error.to_numpy() == pytest.approx(abs(table.estimate - table.truth) / table.truth)
    runs = tiny_run / "results" / "twin-tiny" / "materials" / "slime" / "random" / "L2"
    assert len(list(runs.glob("*/1-cylinder/seed0/log.csv"))) == 1


def test_tiny_minima_table(tiny_run):
    table = pd.read_csv(tiny_run / "results" / "twin-tiny" / "tables" / "minima.csv", dtype={"seed": str})
    assert list(table.start) == ["random", "hand-picked"] and list(table.seed) == ["0", ANY_SEED_LABEL]
    assert (table.dataset == "1-round").all() and (table.val_heightmap_mm > 0).all()
    hand_picked = pd.read_csv(next((tiny_run / "results" / "twin-tiny" / "minima" / "clay" / "hand-picked")
                                   .glob("L1/*/1-round/seed0/log.csv")))
    assert hand_picked.E[0] == HAND_PICKED.E and hand_picked.rho[0] == HAND_PICKED.rho


def test_tiny_heightmap_losses_table(tiny_run):
    table = pd.read_csv(tiny_run / "results" / "twin-tiny" / "tables" / "heightmap_losses.csv")
    assert list(table.loss) == ["heightmap", "neg_heightmap"] * 2
    assert list(table.dataset) == ["1-round", "1-round", "average", "average"]
    assert (table.filter(like="val_") > 0).all().all()


def test_tiny_ladder_reports_the_rung_0_prt_run_for_the_pcd_loss_too(tiny_run):
    table = pd.read_csv(tiny_run / "results" / "twin-tiny" / "tables" / "identifiability_R0.csv")
    by_loss = {loss: rows.drop(columns="loss").reset_index(drop=True) for loss, rows in table.groupby("loss")}
    assert set(by_loss) == {"pcd_cd", "prt_cd"} and len(by_loss["prt_cd"]) == len(IDENTIFIED[1]) + 2
    pd.testing.assert_frame_equal(by_loss["pcd_cd"], by_loss["prt_cd"])
    assert (table.estimate != table.truth).any()  # estimates of a run, not the truth copied
    summary = json.loads((tiny_run / "results" / "twin-tiny" / "identifiability" / "R0" / "L1" / "pcd_cd" / "1-round"
                          / "seed0" / "summary.json").read_text())
    assert summary["same_run_as"] == "prt_cd" and summary["labels"]["loss"] == "pcd_cd"


def test_tiny_analysis_figures(tiny_run):
    for name in ("materials", "minima", "heightmap_losses"):
        assert (tiny_run / "results" / "twin-tiny" / "figures" / f"{name}.png").stat().st_size > 10_000
        assert (tiny_run / "results" / "twin-tiny" / "figures" / f"{name}.pdf").stat().st_size > 1_000
