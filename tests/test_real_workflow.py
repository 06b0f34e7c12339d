"""The main sweep on the published real clay (config/real.yaml): planned from ../shared/real-clay, and a
one-iteration smoke of it that goes from the published meshes to the tables."""

import re

import pandas as pd
import yaml

from conftest import ROOT, shared, snakemake

REAL = ROOT / "config" / "real.yaml"


def _real_config(tmp_path, **identification):
    config = yaml.safe_load(REAL.read_text())
    config["release"]["source"] = str(shared("real-clay"))
    config["identification"].update(identification)
    config.pop("analyses")
    path = tmp_path / "real.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def test_the_real_config_plans_every_pair_and_its_datasets(tmp_path):
    config = yaml.safe_load(REAL.read_text())
    config["release"]["source"] = str(shared("real-clay"))
    (tmp_path / "real.yaml").write_text(yaml.safe_dump(config))
    run = snakemake(tmp_path, "-n", "all", "--quiet", "rules", config=tmp_path / "real.yaml")
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    jobs = dict(line.split()[:2] for line in run.stdout.splitlines() if line.split()[1:2] and line.split()[1].isdigit())
    # five pairs; at level 1 three one-pair datasets and the mix, at level 2 two and the mix
    assert (jobs["import_release"], jobs["prepare"], jobs["identify"], jobs["unseen"]) == ("1", "5", "7", "7")
    assert jobs["landscape"] == "3"  # (E, σ_y) around the hand-picked values on each level-1 pair


def test_runs_and_baselines_use_the_registered_motions(tmp_path):
    """With motion_offsets on (as config/real.yaml has it), the hand-picked baseline simulates the same
    registered path as the identification runs and the unseen-pair checks, not the planned one."""
    config = yaml.safe_load(REAL.read_text())
    assert config["identification"]["motion_offsets"] is True
    config["release"]["source"] = str(shared("real-clay"))
    (tmp_path / "real.yaml").write_text(yaml.safe_dump(config))
    run = snakemake(tmp_path, "-n", "tables", config=tmp_path / "real.yaml")
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    inputs = {}
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", run.stdout):
        rule = re.match(r"(?:local)?rule (\w+):", block)
        if rule and rule.group(1) in ("baseline", "identify", "unseen"):
            inputs.setdefault(rule.group(1), []).extend(re.findall(r"results/real-clay/(\w+)/[^,\s]+\.npz", block))
    assert set(inputs) == {"baseline", "identify", "unseen"}
    assert {folder for folders in inputs.values() for folder in folders} == {"registered"}


def test_a_one_iteration_sweep_recommends_one_row_per_level(tmp_path):
    run = snakemake(tmp_path, "-j2", "tables", config=_real_config(tmp_path, iterations=1, datasets=["mix"],
                                                                uncertainty=False))
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    tables = tmp_path / "results" / "real-clay" / "tables"
    best = pd.read_csv(tables / "best_params.csv")
    assert best.groupby("level").recommended.sum().to_dict() == {1: 1, 2: 1}
    identified = best[best.dataset == "mix"]
    assert (identified.rho == 1330.0).all()  # held
    assert (identified.no_motion_mm > identified.hand_picked_mm).all()
    unseen = pd.read_csv(tables / "generalisation.csv")
    # the level-1 mix is tried on the two level-2 pairs, the level-2 mix on the three level-1 pairs
    assert unseen.groupby("level").pair.nunique().to_dict() == {1: 2, 2: 3}
    assert not (tmp_path / "raw").exists()
