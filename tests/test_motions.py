"""Motions of SPEC §2: planner waypoints, resampling to dt = 0.01 s, trajectory files."""

import math

import numpy as np
import pytest

from dpsi import motions
from dpsi.motions import MOTIONS, Waypoints, plan, read_waypoints, resample, write_waypoints

SPEC = {  # name: (real duration s, real waypoints, sim steps, end offset m, end yaw rad)
    "poking-1": (0.86, 38, 87, (0, 0, 0.015), 0.0),
    "poking-2": (0.93, 40, 94, (0, 0, 0.01), 0.0),
    "poking-shifting-1": (1.52, 68, 152, (-0.03, 0, 0.01), 0.0),
    "poking-shifting-2": (1.50, 54, 153, (0.03, 0, 0.01), 0.0),
    "flattening": (3.74, 275, 378, (-0.025, 0, 0), 0.0),
    "triple-poking": (4.55, 328, 460, (0, -0.025, 0), 0.0),
    "poking-180-rotating": (6.23, 504, 625, (0, 0, 0), math.pi),
}


def test_all_seven_motions_defined():
    assert sorted(MOTIONS) == sorted(SPEC)


@pytest.mark.parametrize("name", SPEC)
@pytest.mark.parametrize("seed", [0, 7])
def test_planner_and_resampling_match_spec(name, seed):
    duration, n_wp, steps, end, end_yaw = SPEC[name]
    wp = plan(MOTIONS[name], seed=seed, start_xyz=(-0.5, 0.01, 0.03), start_yaw=0.3)
    assert len(wp.t) == n_wp
    assert wp.t[0] == 0.0 and wp.duration == pytest.approx(duration, abs=1e-12)
    # uneven time stamps and waypoint spacing within the planner limits
    assert np.ptp(np.diff(wp.t)) > 0.005
    assert np.linalg.norm(np.diff(wp.xyz, axis=0), axis=1).max() <= motions.WAYPOINT_SPACING + 1e-12
    assert np.abs(np.diff(wp.yaw)).max() <= math.radians(5) + 1e-12
    traj = resample(wp)
    assert traj.n_steps == steps
    assert traj.positions.shape == (steps + 1, 3) and traj.yaw.shape == (steps + 1,)
    np.testing.assert_allclose(traj.positions[0], 0, atol=0)
    np.testing.assert_allclose(traj.positions[-1], end, atol=1e-12)
    assert traj.yaw[0] == 0 and traj.yaw[-1] == pytest.approx(end_yaw, abs=1e-12)


def test_planner_is_deterministic_and_seed_dependent():
    m = MOTIONS["poking-2"]
    a, b, c = plan(m, 3), plan(m, 3), plan(m, 4)
    np.testing.assert_array_equal(a.t, b.t)
    assert not np.array_equal(a.t, c.t)


def test_trajectory_passes_every_motion_corner():
    traj = motions.trajectory("poking-shifting-1")
    lowest = traj.positions[:, 2].min()
    assert lowest == pytest.approx(-0.02, abs=1e-12)
    at_bottom = np.isclose(traj.positions[:, 2], -0.02, atol=1e-12)
    assert traj.positions[at_bottom, 0].min() == pytest.approx(-0.03, abs=1e-12)


def test_resampling_uneven_hand_made_trajectory():
    # durations 0.035 s (4 steps), 0.01 s (1 step), 0.1234 s (13 steps)
    t = np.array([0.0, 0.035, 0.045, 0.1684])
    xyz = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0 - 0.007], [1.0, 2.0, 2.99], [1.01, 2.0, 2.99]])
    yaw = np.array([0.5, 0.5, 0.5, 0.5 + 0.2])
    traj = resample(Waypoints(t, xyz, yaw))
    assert traj.n_steps == 4 + 1 + 13
    vel, yaw_rate = traj.velocities()
    # full steps of a segment move at distance / segment duration; the last step is shortened
    np.testing.assert_allclose(vel[:3, 2], -0.007 / 0.035)
    assert vel[3, 2] == pytest.approx(-0.007 / 0.035 * 0.5)
    assert vel[4, 2] == pytest.approx(-0.003 / 0.01)
    np.testing.assert_allclose(vel[5:17, 0], 0.01 / 0.1234)
    np.testing.assert_allclose(yaw_rate[5:17], 0.2 / 0.1234)
    assert vel[17, 0] == pytest.approx(0.01 / 0.1234 * 0.34)
    np.testing.assert_allclose(traj.positions[[4, 5, 18]], xyz[1:] - xyz[0], atol=1e-15)
    assert traj.yaw[-1] == pytest.approx(0.2)


def test_waypoint_file_round_trip(tmp_path):
    wp = plan(MOTIONS["poking-180-rotating"], seed=1)
    path = tmp_path / "traj.csv"
    write_waypoints(path, wp)
    back = read_waypoints(path)
    np.testing.assert_array_equal(back.t, wp.t)
    np.testing.assert_array_equal(back.xyz, wp.xyz)
    assert resample(back).n_steps == 625
    assert [p.name for p in tmp_path.iterdir()] == ["traj.csv"]


@pytest.mark.parametrize("text, problem", [
    ("t,x,y,z\n0,0,0,0\n1,0,0,0\n", "missing column"),
    ("t,x,y,z,yaw\n0,0,0,0,0\n0,0,0,1,0\n", "increase strictly"),
    ("t,x,y,z,yaw\n0,0,0,0,0\n1,0,nan,1,0\n", "non-finite"),
    ("t,x,y,z,yaw\n0,0,0,0,0\n1,0,a,1,0\n", "non-numeric"),
    ("t,x,y,z,yaw\n0,0,0,0,0\n", "at least 2"),
    ("", "not a readable CSV"),
])
def test_bad_waypoint_files_name_the_file(tmp_path, text, problem):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=problem) as err:
        read_waypoints(path)
    assert str(path) in str(err.value)


def test_unknown_motion_lists_known_names():
    with pytest.raises(KeyError, match="poking-1"):
        motions.get_motion("poking-3")
