"""The Snakemake workflow: configuration checks, lint and format, and a tiny end-to-end run through a
cluster executor plugin (each job a separate submission, so nothing can rely on shared process state)."""

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from conftest import ROOT, TINY, snakemake


def edited_config(tmp_path, edit):
    config = yaml.safe_load(TINY.read_text())
    edit(config)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


@pytest.mark.parametrize("edit, message", [
    (lambda c: c["identification"].update(losses=["prt_chamfer"]), "prt_chamfer"),
    (lambda c: c["identification"].update(datasets=["3-mix"]), "3-mix"),
    (lambda c: c.update(colour="blue"), "colour"),
    (lambda c: c.setdefault("simulator", {}).update(precision="f32"), "precision"),  # float32 was removed
    (lambda c: c["reconstruction"].update(density=-1), "density"),
    (lambda c: c["identification"].update(known={"density": 1200}), "density"),
    (lambda c: c["identification"].update(known={"rho": 5000}), "5000"),
    (lambda c: c["analyses"]["identifiability"].update(ood_landscapes=["R3"]), "R3"),
    (lambda c: c["analyses"]["identifiability"].update(ood_runs={"rungs": ["R2"], "losses": ["prt_chamfer"]}),
     "prt_chamfer"),
    (lambda c: c["analyses"]["identifiability"].update(
        ood_runs={"rungs": ["R2"], "losses": ["heightmap_interior"], "select": "final"}), "final"),
])
def test_bad_config_fails_at_start_up(tmp_path, edit, message):
    run = snakemake(tmp_path, "-n", "tables", config=edited_config(tmp_path, edit))
    assert run.returncode != 0
    output = run.stdout + run.stderr
    assert "validating config" in output and message in output


@pytest.mark.parametrize("edit, message", [
    ({"iterations": {"R0": 1}}, "gives no number for rung R1"),
    ({"iterations": {"R0": 1, "R3": 1}}, "validating config"),
    ({"ood_runs": {"rungs": ["R2"], "losses": ["prt_cd"]}}, "gives no number for rung R2"),
    ({"ood_runs": {"rungs": ["R2"], "losses": ["prt_cd"], "iterations": 3}}, None),  # their own number
])
def test_ladder_iterations_per_rung_must_name_every_rung_and_only_rungs(tmp_path, edit, message):
    config = edited_config(tmp_path, lambda c: c["analyses"]["identifiability"].update(edit))
    run = snakemake(tmp_path, "-n", "identifiability", config=config)
    if message is None:
        assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    else:
        assert run.returncode != 0 and message in run.stdout + run.stderr


def test_ood_landscapes_are_planned_on_the_flattening_datapoint_of_each_named_rung(tmp_path):
    run = snakemake(tmp_path, "-n", "identifiability",
                    config=edited_config(tmp_path, lambda c: c["analyses"]["identifiability"].update(ood_landscapes=["R1"])))
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    assert "identifiability/R1/L1/ood/landscape.npz" in run.stdout
    assert "identifiability/R1/prepared/clay-flattening-cylinder-ood-0.npz" in run.stdout
    assert "identifiability/R0/L1/ood/landscape.npz" not in run.stdout


def test_ood_runs_train_and_validate_on_the_flattening_datapoint_at_each_named_rung(tmp_path):
    edit = {"ood_runs": {"rungs": ["R2"], "losses": ["heightmap_interior"]}, "iterations": 1}
    run = snakemake(tmp_path, "-n", "identifiability",
                    config=edited_config(tmp_path, lambda c: c["analyses"]["identifiability"].update(edit)))
    output = run.stdout + run.stderr
    assert run.returncode == 0, output[-3000:]
    run_folder = "identifiability/R2/L1/heightmap_interior/ood/seed0"
    assert f"{run_folder}/summary.json" in output
    assert "identifiability/R2/L1/ood/reference.json" in output
    assert "identifiability/R1/L1/heightmap_interior/ood/" not in output
    assert "identifiability/R2/L1/prt_emd/ood/" not in output
    job = output[output.index(f"{run_folder}/summary.json") - 2000:output.index(f"{run_folder}/summary.json")]
    job_inputs = job[job.rindex("input:"):]
    assert "prepared/clay-flattening-cylinder-ood-0.npz" in job_inputs
    assert "validation-0.npz" not in job_inputs


def test_dataset_the_datapoints_cannot_form_fails_at_start_up(tmp_path):
    run = snakemake(tmp_path, "-n", "tables",
                    config=edited_config(tmp_path, lambda c: c["identification"].update(datasets=["1-cylinder"])))
    assert run.returncode != 0
    assert "poking-2 with cylinder" in run.stdout + run.stderr


def _raw_project(tmp_path, train_id="train-0", motion="poking-2"):
    """A project folder (tmp_path/outer/project) whose config reads the raw dataset `probe` with a train
    and a validation datapoint of level 1."""
    project = tmp_path / "outer" / "project"
    raw = project / "raw" / "probe"
    raw.mkdir(parents=True)
    rows = [dict(id=train_id, motion=motion, effector="round", level=1, role="train", material="clay"),
            dict(id="validation-0", motion="poking-2", effector="round", level=1, role="validation", material="clay")]
    pd.DataFrame(rows).to_csv(raw / "datapoints.csv", index=False)
    (raw / "validation-0").mkdir()
    config = yaml.safe_load(TINY.read_text())
    del config["twin"], config["analyses"]
    config["dataset"] = "probe"
    config["identification"].update(levels=[1], datasets=["1-round"])
    path = project / "probe.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return project, path


def _files(folder):
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_datapoint_id_with_a_path_is_refused_before_any_file_is_opened(tmp_path):
    """An id climbing out of the project would make Snakemake open (truncate) a log file outside it: here
    logs/probe/trajectory/<id>.log is tmp_path/outer/victim/important.log, and raw/probe/<id> (the job's
    input) an existing folder tmp_path/victim/important."""
    victim = tmp_path / "outer" / "victim" / "important.log"
    victim.parent.mkdir(parents=True)
    victim.write_text("precious\n")
    (tmp_path / "victim" / "important").mkdir(parents=True)
    (tmp_path / "victim" / "important" / "notes.txt").write_text("more\n")
    project, config = _raw_project(tmp_path, train_id="../../../../victim/important")
    outside = {p: b for p, b in _files(tmp_path).items() if project not in p.parents}
    run = snakemake(project, "-j1", "-k", "--until", "trajectory", "--", "tables", config=config)
    assert victim.read_text() == "precious\n"
    assert {p: b for p, b in _files(tmp_path).items() if project not in p.parents} == outside
    assert run.returncode != 0
    output = run.stdout + run.stderr
    assert "datapoints.csv: line 2: id '../../../../victim/important' must be letters, digits" in output
    assert "no path separators" in output


def test_unknown_motion_in_the_table_is_named_at_start_up(tmp_path):
    project, config = _raw_project(tmp_path, motion="poking-9")
    run = snakemake(project, "-n", "tables", config=config)
    assert run.returncode != 0
    output = run.stdout + run.stderr
    assert "datapoints.csv: line 2: unknown motion 'poking-9'" in output and "lacks train datapoints" not in output


def _known_friction(raw, config):
    settings = yaml.safe_load(config.read_text())
    settings["identification"]["known"] = {"mu_table": 1.0}
    config.write_text(yaml.safe_dump(settings, sort_keys=False))


@pytest.mark.parametrize("damage, message", [
    (lambda raw, _: (raw / "dataset.yaml").write_text("table_z: [0.0\n"), "raw/probe/dataset.yaml: not valid YAML"),
    (lambda raw, _: (raw / "dataset.yaml").write_text("table_z: !!python/object/apply:os.getpid []\n"),
     "raw/probe/dataset.yaml (line 1): tags such as"),
    (lambda raw, _: (raw / "dataset.yaml").write_text("effectors: [round]\n"),
     "raw/probe/dataset.yaml: effectors must be a mapping"),
    (lambda raw, _: (raw / "dataset.yaml").write_text(f"effectors: {{mine: {{obj: {raw.parent / 'tool.obj'}}}}}\n"),
     "raw/probe/dataset.yaml: effectors.mine.obj is the absolute path"),
    (_known_friction, "config key identification.known: known parameter(s) ['mu_table'] are not identified at "
                      "level 1"),
])
def test_bad_dataset_yaml_or_known_parameter_is_named_at_start_up(tmp_path, damage, message):
    """Each once gave a traceback while Snakemake planned, a MissingInputException, or (the known friction)
    a failure of the identify job after the whole reconstruction."""
    project, config = _raw_project(tmp_path)
    damage(project / "raw" / "probe", config)
    run = snakemake(project, "-n", "tables", config=config)
    output = run.stdout + run.stderr
    assert run.returncode != 0 and message in output, output[-3000:]
    assert "Traceback" not in output


def test_failing_raw_data_job_writes_its_error_to_its_log(tmp_path):
    """The raw dataset lacks the planner trajectory of poking-2: the job validating each raw datapoint
    (check_raw, before the trajectory stage) fails, its log holding the message naming the file and the
    traceback."""
    project, config = _raw_project(tmp_path)
    (project / "raw" / "probe" / "train-0").mkdir()
    run = snakemake(project, "-j1", "-k", "--until", "trajectory", "--", "tables", config=config)
    assert run.returncode != 0
    for datapoint in ("train-0", "validation-0"):
        log = (project / "results" / "probe" / "logs" / "check_raw" / f"{datapoint}.log").read_text()
        assert "FAILED: " in log and "trajectories/poking-2.csv" in log and "Traceback" in log, log


def test_lint_has_no_findings(tmp_path):
    run = snakemake(tmp_path, "--lint")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Congratulations" in run.stdout + run.stderr


def test_snakefmt_is_clean():
    files = [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]
    run = subprocess.run([shutil.which("snakefmt", path=str(Path(sys.executable).parent)) or "snakefmt",
                          "--check", *map(str, files)], capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_changing_one_stage_parameter_reruns_only_what_depends_on_it(tiny_run, tmp_path):
    """Dry run after a finished run: a new reconstruction density touches filling and everything after
    it, not the twin, fusion, meshing or trajectories."""
    denser = edited_config(tmp_path, lambda c: c["reconstruction"].update(density=9e6))
    run = snakemake(tiny_run, "-n", "tables", "--quiet", "rules", config=denser)
    assert run.returncode == 0, run.stderr
    rerun = set(run.stdout.split())
    assert {"fill", "targets", "prepare", "identify"} <= rerun
    assert not {"twin_table", "twin_datapoint", "fuse", "mesh", "trajectory"} & rerun


def test_tiny_workflow_makes_every_table(tiny_run):
    tables = tiny_run / "results" / "twin-tiny" / "tables"
    motions = pd.read_csv(tables / "motions.csv")
    assert list(motions.columns) == ["motion", "segments", "duration_s", "real_waypoints", "sim_steps"]
    assert list(motions.sim_steps) == [87, 94, 152, 153, 378, 460, 625]
    best = pd.read_csv(tables / "best_params.csv")
    names = ["E", "nu", "rho", "yield_stress", "mu_table", "mu_effector"]
    intervals = [f"{n}_{end}" for n in names for end in ("low", "high")]
    assert list(best.columns) == ["level", "loss", "dataset", *names, "val_heightmap_mm", "hand_picked_mm",
                                  "no_motion_mm", "recommended", "at_bound", *intervals]
    assert set(best.loss) == {"prt_cd", "hand-picked"} and set(best.level) == {1, 2}
    assert best.drop(columns=["dataset", "at_bound", *intervals]).notna().all().all()
    assert (best.val_heightmap_mm > 0).all()
    # the intervals of what each run identified (level 1 holds the frictions), holding its estimate
    for row in best[(best.loss == "prt_cd") & (best.dataset != "average")].itertuples():
        for n in names[:4] if row.level == 1 else names:
            assert getattr(row, f"{n}_low") <= getattr(row, n) <= getattr(row, f"{n}_high"), (row.level, n)
    hand = best[best.loss == "hand-picked"].set_index("level")
    assert (hand.val_heightmap_mm == hand.hand_picked_mm).all() and (hand.no_motion_mm > hand.hand_picked_mm).all()
    assert best.groupby("level").recommended.sum().tolist() == [1, 1]
    generalisation = pd.read_csv(tables / "generalisation.csv")
    assert list(generalisation.columns) == ["level", "loss", "dataset", "seed", "pair", "identified_mm",
                                            "hand_picked_mm", "no_motion_mm", "change"]
    # each run is tried on the clay train and validation datapoints of both levels it did not train on
    assert sorted(generalisation.groupby("level").size()) == [3, 3]
    assert generalisation.change.tolist() == pytest.approx(
        ((generalisation.identified_mm - generalisation.hand_picked_mm) / generalisation.hand_picked_mm).tolist())
    ood = pd.read_csv(tables / "ood_heightmap.csv")
    assert list(ood.columns) == ["motion", "config", "loss", "dataset", "heightmap_mm"]
    assert set(ood.motion) == {"flattening"} and "hand-picked" in set(ood.loss)
    assert ood.heightmap_mm.notna().all() and (ood.heightmap_mm > 0).all()
    recovery = pd.read_csv(tables / "recovery_error.csv")
    assert list(recovery.columns) == ["level", "loss", "dataset", "seed", "parameter", "truth", "estimate",
                                      "rel_error"]
    assert len(recovery) == 2 * (6 + 2) and recovery.rel_error.notna().all()  # 2 runs × (6 parameters + E/ρ, σ_y/E)
    truth = recovery[recovery.seed == recovery.seed.iloc[0]].drop_duplicates(["level", "parameter"]).set_index(
        ["level", "parameter"]).truth
    level = recovery.level.iloc[0]
    assert truth[(level, "E/rho")] == pytest.approx(truth[(level, "E")] / truth[(level, "rho")])
    for name in ("motions", "parameters", "best_params", "generalisation", "ood_heightmap", "recovery_error",
                 "uncertainty", "identifiability_R0_uncertainty", "identifiability_R0_coverage"):
        assert (tables / f"{name}.md").read_text().count("|") > 10
        assert r"\toprule" in (tables / f"{name}.tex").read_text()
        assert (tables / f"{name}.csv.provenance.json").is_file()


def test_a_run_s_summary_and_the_uncertainty_tables_carry_the_same_intervals(tiny_run):
    """The main sweep's uncertainty.csv and the R0 ladder's table hold each run's uncertainty block as is."""
    results = tiny_run / "results" / "twin-tiny"
    tables = results / "tables"
    columns = ["rung", "level", "loss", "dataset", "seed", "quantity", "estimate", "low", "high", "determined", "truth"]
    for table, summaries in (("uncertainty", sorted(results.glob("runs/L*/prt_cd/1-round/seed0/summary.json"))),
                             ("identifiability_R0_uncertainty",
                              [results / "identifiability/R0/L1/prt_cd/1-round/seed0/summary.json"])):
        rows = pd.read_csv(tables / f"{table}.csv", keep_default_na=False, na_values=[""])
        assert list(rows.columns) == columns and len(summaries) >= 1
        for path in summaries:
            summary = json.loads(path.read_text())
            block = summary["uncertainty"]
            assert block["iteration"] == summary["best"]["iteration"] and "error" not in block
            mine = rows[(rows.level == summary["level"]) & (rows.loss == summary["loss"])]
            assert mine[["quantity", "estimate", "low", "high", "determined"]].to_dict("records") == [
                {k: q[k] for k in ("quantity", "estimate", "low", "high", "determined")} for q in block["quantities"]]
            assert mine.truth.notna().all() and (mine.rung.isna().all() if table == "uncertainty"
                                                 else (mine.rung == "R0").all())


def test_tiny_workflow_makes_figures(tiny_run):
    figures = tiny_run / "results" / "twin-tiny" / "figures"
    for name in ("runs_L1", "runs_L2", "heightmaps_clay-flattening-cylinder-ood-0", "uncertainty",
                 "identifiability_R0_uncertainty"):
        assert (figures / f"{name}.png").stat().st_size > 10_000
        assert (figures / f"{name}.pdf").stat().st_size > 1_000


def test_rerun_of_a_finished_workflow_does_nothing(tiny_run):
    run = snakemake(tiny_run, "-n", "tables", "figures")
    assert run.returncode == 0 and "Nothing to be done" in run.stdout + run.stderr


def _checksums(folder):
    return {p.relative_to(folder): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}


def test_a_users_raw_dataset_is_only_read_by_a_full_run(tiny_run, tmp_path):
    """A user's captures under raw/<name>/ (here the tiny twin's, without its truth) identified with a config
    that still has a twin section: the run reads them, leaves every byte as it was, writes nothing else under
    raw/, and keeps its results, tables and logs under results/<name>/."""
    raw = tmp_path / "raw" / "mine"
    shutil.copytree(tiny_run / "results" / "twin-tiny" / "raw", raw, ignore=shutil.ignore_patterns("truth.json"))
    before = _checksums(tmp_path / "raw")
    def users_config(c):  # no analyses and no intervals (tested on the tiny run): the identification only
        c.pop("analyses")
        c["identification"]["uncertainty"] = False

    config = edited_config(tmp_path, users_config)
    run = snakemake(tmp_path, "-j2", "tables", "--config", "dataset=mine", config=config)
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    assert _checksums(tmp_path / "raw") == before
    assert (tmp_path / "results" / "mine" / "tables" / "best_params.csv").is_file()
    assert (tmp_path / "results" / "mine" / "logs" / "tables.log").is_file()
    assert not (tmp_path / "results" / "twin-tiny").exists()


def test_the_twin_is_generated_only_under_its_results_folder(tiny_run):
    assert (tiny_run / "results" / "twin-tiny" / "raw" / "datapoints.csv").is_file()
    assert not (tiny_run / "raw").exists()


@pytest.mark.parametrize("key, value", [("results", ".."), ("results", "/tmp/x"), ("results", "/"),
                                        ("results", "a/../../b"), ("dataset", ".."), ("dataset", "a/b")])
def test_a_path_leaving_the_project_is_refused_at_start_up(tmp_path, key, value):
    project = tmp_path / "project"
    project.mkdir()
    run = snakemake(project, "-n", "tables", "--config", f"{key}={value}")
    assert run.returncode != 0
    assert f"`{key}`" in run.stdout + run.stderr or f"'{key}'" in run.stdout + run.stderr
    assert {p.name for p in tmp_path.iterdir()} == {"project"}
