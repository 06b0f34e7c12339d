"""The command line ``python -m dpsi`` on a small box mesh (before) and a squashed box cloud (after)."""

import json
import math
import subprocess
import sys

import open3d as o3d
import pytest

from dpsi.__main__ import main
from dpsi.parameters import HAND_PICKED
from dpsi.pointclouds import write_mesh, write_points
from dpsi.prepare import surface_points

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


@pytest.mark.parametrize("command, options", [
    ([], ["simulate", "identify"]),
    (["simulate"], ["--before", "--after", "--motion", "--effector", "--param", "--density", "--table-z", "--json"]),
    (["identify"], ["--before", "--validate", "--loss", "--level", "--seed", "--iterations", "--initial", "--out"]),
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
