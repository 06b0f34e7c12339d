"""The command line ``python -m dpsi`` on a small box mesh (before) and a squashed box cloud (after)."""

import json
import math
import re
import signal
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from dpsi import __main__ as cli
from dpsi.__main__ import build_parser, main
from dpsi.parameters import HAND_PICKED
from dpsi.pointclouds import write_mesh, write_points
from dpsi.prepare import surface_points
from dpsi.reporting.tables import uncertainty_table
from dpsi.uncertainty import describe
from dpsi.simulation import SimulationError, Simulator, memory

KEYS = {"particles", "heightmap_mm", "pcd_cd", "prt_cd", "pcd_emd", "prt_emd", "params", "repairs"}


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
    assert all(math.isfinite(result[k]) and result[k] > 0 for k in KEYS - {"params", "particles", "repairs"})
    assert result["repairs"] == []
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
    """A closed sphere mesh with its top (100 of 360 faces) deleted: more than a scan's small holes, which
    are repaired (tests/test_repair.py)."""
    mesh = o3d.geometry.TriangleMesh.create_sphere(0.015, resolution=10).translate((0, 0, 0.015))
    mesh.triangles = o3d.utility.Vector3iVector(np.asarray(mesh.triangles)[100:])
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


def _floating(folder):
    write_mesh(folder / "float.obj", _box(0.03, 0.025).translate((0.0, 0.0, 0.05)))
    return folder / "float.obj"


def _faces_marked_deleted(folder):
    """The box as an ASCII PLY whose faces carry MeshLab's 'flags' with the deleted bit set."""
    box = _box(0.03, 0.025)
    v, f = np.asarray(box.vertices), np.asarray(box.triangles)
    (folder / "flags.ply").write_text(
        f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nproperty int flags\nend_header\n"
        + "".join(f"{x} {y} {z}\n" for x, y, z in v) + "".join(f"3 {a} {b} {c} 1\n" for a, b, c in f))
    return folder / "flags.ply"


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
    (lambda d: {"before": _floating(d), "table_z": "0"},
     lambda d: f"{d / 'float.obj'}: its bottom is 50.0 mm above the table (z = 0 m): it would fall"),
    (lambda d: {"table_z": "0.1"}, lambda d: "before.obj: its bottom is 100.0 mm below the table (z = 0.1 m): it is "
                                             "sunk into the table"),
    (lambda d: {"motion": "flattening"}, lambda d: "motion flattening is made with the cylinder effector (SPEC §2), "
                                                   "not round"),
    (lambda d: {"before": d / "x.stl"}, lambda d: f"{d / 'x.stl'}: unsupported shape file type '.stl'; use a point "
                                                  "cloud (.ply, .pcd, .xyz, .npy) or a watertight mesh (.obj, or .ply "
                                                  "with faces)"),
    (lambda d: {"after": _faces_marked_deleted(d)},
     lambda d: f"{d / 'flags.ply'}: the header declares 12 faces but PyMeshLab read none"),
])
def test_unusable_shapes_are_refused_before_simulating(capsys, monkeypatch, shapes, tmp_path, broken, message):
    monkeypatch.setattr(cli, "Simulator", lambda config: pytest.fail("a simulator was started"))
    assert main(["simulate", *_options(shapes, **broken(tmp_path))]) == 1
    error = capsys.readouterr().err
    assert error.startswith("dpsi simulate: error: ") and message(tmp_path) in error, error


def test_identify_names_a_table_above_the_shape(capsys, monkeypatch, shapes, tmp_path):
    """`identify --table-z 0.1` reported the initial values, without the cause `simulate` gave."""
    monkeypatch.setattr(cli, "Simulator", lambda config: pytest.fail("a simulator was started"))
    assert main(["identify", *_options(shapes, table_z="0.1"), "--loss", "prt_cd", "--out", str(tmp_path)]) == 1
    assert "before.obj: its bottom is 100.0 mm below the table (z = 0.1 m)" in capsys.readouterr().err


def test_suspicious_shapes_are_warned_about(capsys, shapes, tmp_path):
    write_mesh(tmp_path / "taller.obj", _box(0.03, 0.03))
    args = build_parser().parse_args(["simulate", *_options(shapes, after=tmp_path / "taller.obj")])
    cli._shapes_datapoint(args.before, args.after, args.motion, args.effector, args.density, args.table_z,
                          cli.SimulatorConfig())
    assert re.search(r"^dpsi: warning: .*taller\.obj: its top is \d\.\d mm higher than the top of .*before\.obj; the "
                     r"motions press the clay down — are before and after swapped\?$", capsys.readouterr().err, re.M)


def test_identified_parameter_on_its_bound_is_marked(capsys, monkeypatch, shapes, tmp_path):
    """E clipped to its upper bound is marked; μ_t = 2 (its upper bound too) is fixed at level 1, not identified."""
    values = {**HAND_PICKED.replace(E=3e5, mu_table=2.0, mu_effector=0.3).as_dict()}
    best = {"iteration": 4, "parameters": values, "validation": {"heightmap_mm": 2000.0}}
    monkeypatch.setattr(cli, "identify", lambda *args, **kwargs: {"best": best, "final": best})
    monkeypatch.setattr(cli, "Simulator", lambda config: None)
    assert main(["identify", *shapes, "--loss", "prt_cd", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "E: 300000 Pa (at its upper bound: the data may want a value outside the range)" in out
    assert "mu_table: 2 -\n" in out and "nu: 0.4 -\n" in out


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


def test_a_known_parameter_is_held_through_the_run(shapes, tmp_path):
    done = _run("identify", *shapes, "--loss", "heightmap", "--iterations", "2", "--initial", "hand-picked",
                "--known", "rho=1500", "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["known"] == ["rho"]
    assert summary["best"]["parameters"]["rho"] == summary["final"]["parameters"]["rho"] == 1500.0
    assert summary["final"]["parameters"]["E"] != HAND_PICKED.E  # the others moved
    assert "rho: 1500 kg/m^3" in done.stdout and "rho was held" in done.stdout


def test_a_datapoints_file_with_two_motions_trains_on_both(shapes, tmp_path):
    before, after = shapes[1], shapes[3]
    table = tmp_path / "points.csv"
    table.write_text(f"before, after, motion, effector\n{before},{after},poking-1,round\n"
                     f"{before},{after},poking-2,cylinder\n")
    done = _run("identify", "--datapoints", str(table), "--density", "1e7", "--loss", "prt_emd", "--iterations", "1",
                "--initial", "hand-picked", "--out", str(tmp_path / "run"))
    assert done.returncode == 0, done.stderr
    training = json.loads((tmp_path / "run" / "summary.json").read_text())["training"]
    assert [steps for _, _, steps in training] == [87, 94]  # poking-1 and poking-2 (SPEC §2)


def test_a_datapoints_file_missing_a_column_is_named(capsys, tmp_path):
    table = tmp_path / "points.csv"
    table.write_text("before,after,motion\na.obj,b.obj,poking-1\n")
    with pytest.raises(SystemExit):
        main(["identify", "--datapoints", str(table), "--loss", "prt_emd", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert "points.csv" in err and "missing ['effector']" in err


def test_a_repaired_before_mesh_is_reported(tmp_path):
    box = o3d.geometry.TriangleMesh.create_box(0.03, 0.03, 0.025).translate((-0.015, -0.015, 0.0))
    box = box.subdivide_midpoint(2)
    faces = np.asarray(box.triangles).copy()
    faces[3] = faces[20]  # one face listed twice where a triangle is missing, as in a published scan
    broken = o3d.geometry.TriangleMesh(box.vertices, o3d.utility.Vector3iVector(faces))
    write_mesh(tmp_path / "scan.obj", broken)
    write_points(tmp_path / "after.ply", surface_points(_box(0.032, 0.021)))
    done = _run("simulate", "--before", str(tmp_path / "scan.obj"), "--after", str(tmp_path / "after.ply"),
                "--motion", "poking-1", "--effector", "round", "--density", "1e7", "--json")
    assert done.returncode == 0, done.stderr
    repairs = {r["what"]: r for r in json.loads(done.stdout)["repairs"]}
    assert repairs["duplicated face(s) removed"]["count"] == 1
    assert repairs["face(s) added to close holes"]["file"] == str(tmp_path / "scan.obj")


def test_an_out_that_is_a_file_is_named_before_the_shapes_are_prepared(capsys, monkeypatch, shapes, tmp_path):
    (tmp_path / "run").write_text("")
    monkeypatch.setattr(cli, "_shapes_datapoint", lambda *args: pytest.fail("shapes prepared"))
    assert main(["identify", *shapes, "--loss", "prt_cd", "--out", str(tmp_path / "run")]) == 1
    assert capsys.readouterr().err == (f"dpsi identify: error: output folder {tmp_path / 'run'} is a file; give a "
                                       "folder (it is created if missing)\n")


def test_a_run_whose_simulations_all_fail_exits_non_zero_with_the_cause(capsys, monkeypatch, shapes, tmp_path):
    def unstable(self, scene, params, keep_substeps=True):
        raise SimulationError("step 4 of 250 produced NaN or inf")

    monkeypatch.setattr(Simulator, "forward", unstable)
    assert main(["identify", *shapes, "--loss", "prt_cd", "--iterations", "2", "--out", str(tmp_path)]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.endswith("dpsi identify: error: nothing to learn from at iteration 0: every training "
                                      "datapoint was skipped (parameters " + err.split("(parameters ")[1])
    assert "before: simulation failed: step 4 of 250 produced NaN or inf" in err
    assert not (tmp_path / "summary.json").exists()


def test_ctrl_c_exits_with_130_one_line_and_a_resume_hint(shapes, tmp_path):
    """SIGINT once the first iteration is saved; the same command then resumes from it."""
    args = [sys.executable, "-m", "dpsi", "identify", *shapes, "--loss", "prt_cd", "--iterations", "3",
            "--initial", "hand-picked", "--out", str(tmp_path)]
    # a shell's background job inherits SIGINT ignored, and Python then keeps it so: restore the default
    run = subprocess.Popen(args, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    for line in run.stderr:
        lines.append(line)
        if line.startswith("identify L1 prt_cd seed 0 1/3"):
            run.send_signal(signal.SIGINT)
            break
    rest = run.stderr.read()
    assert run.wait(timeout=600) == 130, "".join(lines) + rest
    assert rest.strip().splitlines()[-1] == (f"dpsi identify: interrupted; run the same command again to resume from "
                                            f"its last completed iteration (kept in {tmp_path})")
    assert "Traceback" not in rest and not (tmp_path / ".dpsi.lock").exists()
    again = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert "seed 0 1/3" not in again.stderr and "seed 0 3/3" in again.stderr  # resumed after row 1


def test_a_capacity_beyond_the_memory_is_refused_naming_the_option(capsys, monkeypatch, shapes):
    monkeypatch.setattr(memory, "available_memory", lambda: 24e9)
    assert main(["simulate", *shapes, "--max-particles", "1000000"]) == 1
    error = capsys.readouterr().err
    assert error.startswith("dpsi simulate: error: the simulator would need 45.5 GB") and error.count("\n") == 1
    assert "lower simulator.max_particles (now 1000000; --max-particles on the command line)" in error
