"""The command line ``python -m dpsi`` on a small box mesh (before) and a squashed box cloud (after)."""

import json
import math
import re
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from dpsi import __main__ as cli
from dpsi.__main__ import main
from dpsi.parameters import HAND_PICKED
from dpsi.pointclouds import write_mesh, write_points
from dpsi.prepare import surface_points
from dpsi.reporting.tables import uncertainty_table
from dpsi.uncertainty import describe

KEYS = {"particles", "heightmap_mm", "pcd_cd", "prt_cd", "pcd_emd", "prt_emd", "params"}


def _box(width: float, height: float) -> o3d.geometry.TriangleMesh:
    box = o3d.geometry.TriangleMesh.create_box(width, width, height)
    return box.translate((-width / 2, -width / 2, 0.0))


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    """Arguments naming a 3 × 3 × 2.5 cm box mesh (before) and a lower, wider box's surface cloud (after),
    at a density giving a few hundred particles."""
    folder = tmp_path_factory.mktemp("shapes")
    write_mesh(folder / "before.obj", _box(0.03, 0.025))
    write_points(folder / "after.ply", surface_points(_box(0.032, 0.021)))
    return ["--before", str(folder / "before.obj"), "--after", str(folder / "after.ply"),
            "--motion", "poking-1", "--effector", "round", "--density", "1e7"]


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dpsi", *args], capture_output=True, text=True, timeout=600)


def test_simulate_json_prints_the_documented_keys(shapes):
    done = _run("simulate", *shapes, "--param", "E=40000", "--param", "nu=0.3", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert set(result) == KEYS
    assert 100 < result["particles"] < 1000
    assert all(math.isfinite(result[k]) and result[k] > 0 for k in KEYS - {"params", "particles"})
    assert result["params"] == {**HAND_PICKED.as_dict(), "E": 40000.0, "nu": 0.3}


def test_identify_saves_and_prints_the_parameters(shapes, tmp_path):
    done = _run("identify", *shapes, "--loss", "prt_emd", "--iterations", "1", "--initial", "hand-picked",
                "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["best"]["iteration"] == 1 and summary["completed_iterations"] == 1
    assert f"E: {summary['best']['parameters']['E']:g} Pa" in done.stdout
    assert "identify L1 prt_emd seed 0 1/1" in done.stderr  # plain progress lines when not a terminal
    # what the data determine, one line per quantity, as the summary has it
    assert "what the data determine" in done.stdout
    for quantity in summary["uncertainty"]["quantities"]:
        assert f"  {describe(quantity)}" in done.stdout.splitlines()


def test_identify_json_is_the_summary_with_its_intervals_and_the_table_repeats_them(shapes, tmp_path):
    done = _run("identify", *shapes, "--loss", "prt_emd", "--iterations", "1", "--initial", "hand-picked",
                "--out", str(tmp_path), "--json")
    assert done.returncode == 0, done.stderr
    printed = json.loads(done.stdout)
    assert printed == json.loads((tmp_path / "summary.json").read_text())
    block = printed["uncertainty"]
    assert block["iteration"] == printed["best"]["iteration"] and block["tolerance_mm"] > 0
    assert [q["quantity"] for q in block["quantities"]][:6] == ["E", "nu", "rho", "yield_stress", "E/rho",
                                                                 "yield_stress/E"]
    assert block["quantities"][0]["estimate"] == pytest.approx(printed["best"]["parameters"]["E"])
    rows = uncertainty_table([{**printed, "level": 1, "loss": "prt_emd", "dataset": "cli", "seed": 0}])
    columns = ["quantity", "estimate", "low", "high", "determined"]
    assert rows[columns].to_dict("records") == [{k: q[k] for k in columns} for q in block["quantities"]]
    assert rows.rung.eq("").all() and rows.truth.isna().all()
    undetermined = _run("identify", *shapes, "--loss", "prt_emd", "--iterations", "1", "--initial", "hand-picked",
                        "--out", str(tmp_path / "none"), "--no-uncertainty", "--json")
    assert "uncertainty" not in json.loads(undetermined.stdout)


@pytest.mark.parametrize("command, options", [
    ([], ["simulate", "identify"]),
    (["simulate"], ["--before", "--after", "--motion", "--effector", "--param", "--density", "--table-z",
                    "--max-particles", "--json"]),
    (["identify"], ["--before", "--validate", "--loss", "--level", "--seed", "--iterations", "--initial", "--out",
                    "--max-particles", "--uncertainty", "--json"]),
])
def test_help_documents_every_option(capsys, command, options):
    with pytest.raises(SystemExit) as exit_:
        main([*command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert all(option in text for option in options)


@pytest.mark.parametrize("param, message", [
    ("stiffness=3", "unknown parameter 'stiffness'"),
    ("E=soft", "value of E must be a number, got 'soft'"),
    ("E", "expected NAME=VALUE, got 'E'"),
    ("nu=0.6", "parameter nu=0.6 - is outside its range"),
])
def test_bad_param_is_named(capsys, shapes, param, message):
    with pytest.raises(SystemExit) as exit_:
        main(["simulate", *shapes, "--param", param])
    assert exit_.value.code == 2
    error = capsys.readouterr().err
    assert "argument --param" in error and message in error


def test_identify_does_not_resume_the_state_of_other_shapes(shapes, tmp_path):
    """The same --out with another after shape and effector: the state of the first run is refused, not
    resumed (which printed the first run's result)."""
    first = _run("identify", *shapes, "--loss", "prt_emd", "--iterations", "1", "--out", str(tmp_path))
    assert first.returncode == 0, first.stderr
    other_after = tmp_path / "other_after.ply"
    write_points(other_after, surface_points(_box(0.034, 0.019)))
    other = [*shapes[:2], "--after", str(other_after), *shapes[4:6], "--effector", "rectangle", *shapes[8:]]
    second = _run("identify", *other, "--loss", "prt_emd", "--iterations", "1", "--out", str(tmp_path))
    assert second.returncode == 1 and "best iteration" not in second.stdout
    assert "state.json belongs to a run of other inputs" in second.stderr and "another output folder" in second.stderr


def _options(shapes, **change):
    """``shapes`` with options replaced: change={"before": path, "density": "1e12"}."""
    args = list(shapes)
    for name, value in change.items():
        flag = "--" + name.replace("_", "-")
        if flag in args:
            args[args.index(flag) + 1] = str(value)
        else:
            args += [flag, str(value)]
    return args


def _open_mesh(folder):
    """A closed sphere mesh with 20 of its faces deleted."""
    mesh = o3d.geometry.TriangleMesh.create_sphere(0.015, resolution=10).translate((0, 0, 0.015))
    mesh.triangles = o3d.utility.Vector3iVector(np.asarray(mesh.triangles)[20:])
    write_mesh(folder / "open.obj", mesh)
    return folder / "open.obj"


def _nan_vertex(folder):
    write_mesh(folder / "box.obj", _box(0.03, 0.025))
    lines = (folder / "box.obj").read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("v "))
    lines[k] = "v 0.015 nan 0.0"
    (folder / "nan.obj").write_text("\n".join(lines) + "\n")
    return folder / "nan.obj", k + 1


def _millimetres(folder):
    write_mesh(folder / "mm.obj", _box(30.0, 25.0))
    return folder / "mm.obj"


@pytest.mark.parametrize("broken, message", [
    (lambda d: {"before": _open_mesh(d)}, lambda d: f"{d / 'open.obj'}: mesh is not watertight"),
    (lambda d: {"after": _nan_vertex(d)[0]},
     lambda d: f"{d / 'nan.obj'}, line {_nan_vertex(d)[1]}: vertex '0.015 nan 0.0' is not three finite numbers"),
    (lambda d: {"before": _millimetres(d)}, lambda d: "the object is 30 m across (30 × 30 × 25 m), larger than the "
                                                      "simulated box 0.21 × 0.21 × 0.1 m — are the units millimetres?"),
    (lambda d: {"density": "1e12"}, lambda d: "gives ~2.25e+07 particles in the 22.5 cm³ object, the simulator "
                                              "holds 5000: lower the density to at most ~2.2e+08 particles/m³"),
    (lambda d: {"max_particles": "100"}, lambda d: "the simulator holds 100"),
    (lambda d: {"density": "3e6"}, lambda d: "at --density 3e+06 the object has 100 particles, fewer than the "
                                             "170 points of the PCD target"),
])
def test_unusable_shapes_are_refused_before_simulating(capsys, monkeypatch, shapes, tmp_path, broken, message):
    monkeypatch.setattr(cli, "Simulator", lambda config: pytest.fail("a simulator was started"))
    assert main(["simulate", *_options(shapes, **broken(tmp_path))]) == 1
    error = capsys.readouterr().err
    assert error.startswith("dpsi simulate: error: ") and message(tmp_path) in error, error


def test_too_low_density_names_one_that_works(capsys, monkeypatch, shapes):
    """At 3e6 particles/m³ the PCD target has more points than the object particles (the EMD fails);
    the density the message names simulates."""
    monkeypatch.setattr(cli, "Simulator", lambda config: pytest.fail("a simulator was started"))
    assert main(["simulate", *_options(shapes, density="3e6")]) == 1
    error = capsys.readouterr().err
    suggested = re.search(r"use --density ([0-9.e+]+) or more", error)[1]
    done = _run("simulate", *_options(shapes, density=suggested), "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["pcd_emd"] > 0


@pytest.mark.parametrize("command, option, message", [
    (["identify", "--loss", "prt_cd", "--iterations", "1", "--param", "mu_table=0.5"], [],
     "argument --param: level 1 keeps mu_table fixed"),
    (["simulate"], ["--table-z", "nan"], "argument --table-z: must be a finite number, got 'nan'"),
])
def test_ignored_or_non_finite_options_are_refused(capsys, shapes, tmp_path, command, option, message):
    out = ["--out", str(tmp_path / "run")] if command[0] == "identify" else []
    with pytest.raises(SystemExit) as exit_:
        main([command[0], *shapes, *command[1:], *out, *option])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
