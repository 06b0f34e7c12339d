"""Physically impossible captures are refused and suspicious ones warned about, naming the shape and the
number; a good synthetic pair and the published real pairs pass."""

import dataclasses
import re

import open3d as o3d
import pytest

from conftest import shared
from dpsi.__main__ import _shapes_datapoint
from dpsi.effectors import ROUND
from dpsi.motions import Trajectory, trajectory
from dpsi.plausibility import ImplausibleInput, check_plausible, findings
from dpsi.prepare import after_targets, assemble, fill_particles, surface_points
from dpsi.shapes import lump
from dpsi.simulation import SimulatorConfig

DENSITY = 1e7
BEFORE = lump((0.03, 0.025), wall=0.012, top=0.03)
AFTER = lump((0.032, 0.027), wall=0.010, top=0.024)  # pressed: lower and a little wider


def _datapoint(before=BEFORE, after=AFTER, motion="poking-1", start=None):
    particles = fill_particles(before, DENSITY)
    targets = after_targets(after, surface_points(after), particles, DENSITY, 0.0, measured=False)
    lo, hi = before.get_min_bound(), before.get_max_bound()
    top_centre = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]]
    return assemble("lump", motion, ROUND, particles, DENSITY, trajectory(motion),
                    top_centre if start is None else start, targets)


@pytest.fixture(scope="module")
def good():
    return _datapoint()


def _moved(mesh, shift):
    return o3d.geometry.TriangleMesh(mesh).translate(shift)


def test_a_pressed_lump_passes(good):
    found = findings(good)
    assert (found.errors, found.warnings) == ([], [])


def _path(good, jump):
    """The poking-1 path with the tip moving ``jump`` m down in its 10th step."""
    positions = good.trajectory.positions.copy()
    positions[10:, 2] -= jump
    return dataclasses.replace(good, trajectory=Trajectory(positions, good.trajectory.yaw, good.trajectory.dt))


CASES = {
    "floating 5 cm": (lambda g: _datapoint(_moved(BEFORE, (0, 0, 0.05)), _moved(AFTER, (0, 0, 0.05))), True,
                      r"the before shape: its bottom is 50\.0 mm above the table \(z = 0 m\): it would fall"),
    "floating 6 mm": (lambda g: dataclasses.replace(g, table_z=-0.006), False,
                      r"its bottom is 6\.0 mm above the table \(z = -0\.006 m\)"),
    "sunk into the table": (lambda g: dataclasses.replace(g, table_z=0.01), True,
                            r"its bottom is 10\.0 mm below the table \(z = 0\.01 m\): it is sunk into the table"),
    "after 0.5 m away": (lambda g: _datapoint(after=_moved(AFTER, (0.5, 0, 0))), True,
                         r"the after shape: its footprint does not overlap the before shape's \(centres 500\.0 mm "
                         "apart"),
    "after moved 2 cm by a poke": (lambda g: _datapoint(after=_moved(AFTER, (0, 0.02, 0))), False,
                                   r"its footprint's centre lies 20\.0 mm from the before shape's \(x 0\.0 mm, y "
                                   r"20\.0 mm\), more than the tool moves sideways \(0\.0 mm in x, 0\.0 mm in y\)"),
    "before and after swapped": (lambda g: _datapoint(AFTER, BEFORE), False,
                                 r"the after shape: its top is \d\.\d mm higher than the top of the before shape; "
                                 "the motions press the clay down — are before and after swapped"),
    "after 2 cm taller": (lambda g: _datapoint(after=lump((0.03, 0.025), wall=0.03, top=0.05)), True,
                          r"its top is 2\d\.\d mm higher than the top of the before shape"),
    "path above the object": (lambda g: dataclasses.replace(g, start=g.start + [0, 0, 0.02]), True,
                              r"the effector path: the effector never reaches the before shape \(the effector "
                              r"stays \d\.\d mm above it\)"),
    "path beside the object": (lambda g: dataclasses.replace(g, start=g.start + [0.1, 0, 0]), True,
                               r"the effector never reaches the before shape \(nothing of it lies under the "
                               "effector"),
    "start inside the clay": (lambda g: dataclasses.replace(g, start=g.start - [0, 0, 0.01]), True,
                              r"the effector path: the tip starts \d\.\d mm inside the before shape"),
    "tip jumping 5 cm in 0.02 s": (lambda g: _path(g, 0.05), True,
                                   r"the tip moves at 5\.\d\d m/s in step 10 \(50\.\d mm in 0.01 s\)"),
    "tip at 0.5 m/s": (lambda g: _path(g, 0.005), False, r"the tip moves at 0\.5\d m/s in step 10"),
}


@pytest.mark.parametrize("case", CASES)
def test_implausible_capture_is_named(good, case):
    make, impossible, message = CASES[case]
    dp = make(good)
    found = findings(dp)
    assert len(found.errors if impossible else found.warnings) == 1, (found.errors, found.warnings)
    assert re.search(message, (found.errors if impossible else found.warnings)[0]), found
    if impossible:
        with pytest.raises(ImplausibleInput, match=message):
            check_plausible(dp)
    else:
        assert found.errors == [] and check_plausible(dp) == found.warnings


REAL_PAIRS = {  # robot-frame pairs of ../shared/real-clay (its README), table at z = 0, with their motions
    "data-motion-1/eef-rectangle/mesh_8": ("poking-1", "rectangle"),
    "data-motion-poking-1/eef-cylinder/mesh_5": ("poking-1", "cylinder"),
    "data-motion-poking-shifting-1/eef-cylinder/mesh_1": ("poking-shifting-1", "cylinder"),
    "data-motion-poking-shifting-2/eef-round/mesh_0": ("poking-shifting-2", "round"),
}


@pytest.mark.parametrize("pair", REAL_PAIRS)
def test_published_real_pairs_pass(pair, capsys):
    """As `dpsi simulate --table-z 0` reads them: no error, no warning."""
    folder = shared("real-clay")
    motion, effector = REAL_PAIRS[pair]
    dp = _shapes_datapoint(str(folder / f"{pair}0.obj"), str(folder / f"{pair}1.obj"), motion, effector, 4e7, 0.0,
                           SimulatorConfig())
    found = findings(dp)
    assert (found.errors, found.warnings) == ([], [])
    assert "warning" not in capsys.readouterr().err
