"""The seven robot motions (SPEC §2), a synthetic motion planner and trajectory resampling.

Units: metres, radians, seconds. Directions are in the robot base frame; yaw is the rotation about +z.

A *motion* is a list of straight segments (translate along an axis, or rotate about z). A real motion
planner turns it into *waypoints* (tip poses with uneven time stamps); :func:`resample` turns waypoints
into a :class:`Trajectory` with a constant step dt = 0.01 s for the simulator.

Resampling rule (SPEC §2): between waypoints j and j+1 (duration d_j) the tip moves at the constant
velocity (p_{j+1} − p_j)/d_j. Every waypoint interval starts on a step boundary and takes
``ceil(d_j / dt)`` steps; all its steps move v·dt except the last, which is shortened so that the tip
lands exactly on waypoint j+1. The simulation step count is therefore Σ_j ceil(d_j/dt), at least the
real duration / dt, and the SPEC's "sim steps" column is :attr:`Trajectory.n_steps` (the trajectory holds
``n_steps + 1`` poses: the start and the pose after every step).

The rectangle effector's initial 45° yaw is not part of any trajectory: the effector carries it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from dpsi.csv_files import read_csv
from dpsi.files import atomic_output

DT = 0.01
"""Simulation step (s)."""

WAYPOINT_SPACING = 0.002
"""Largest translation between consecutive planner waypoints (m)."""

WAYPOINT_ANGLE = math.radians(5.0)
"""Largest rotation between consecutive planner waypoints (rad)."""

_AXES = {"x": 0, "y": 1, "z": 2}
_TOL = 1e-6
"""Tolerance, in steps, when counting the steps of a waypoint interval (absorbs float round-off)."""


@dataclass(frozen=True)
class Segment:
    """One straight piece of a motion: ``kind`` 'translate' (``amount`` in m along ``axis``) or
    'rotate' (``amount`` in rad about ``axis``, which must be 'z'). The sign of ``amount`` is the direction."""

    kind: str
    axis: str
    amount: float

    def __post_init__(self):
        if self.kind not in ("translate", "rotate"):
            raise ValueError(f"segment kind must be 'translate' or 'rotate', not {self.kind!r}")
        if self.axis not in _AXES or (self.kind == "rotate" and self.axis != "z"):
            raise ValueError(f"bad axis {self.axis!r} for a {self.kind} segment (rotations are about z only)")
        if not np.isfinite(self.amount) or self.amount == 0:
            raise ValueError(f"segment amount must be finite and non-zero, not {self.amount}")

    def min_intervals(self) -> int:
        """Fewest planner waypoint intervals that keep them within 0.002 m / 5°."""
        limit = WAYPOINT_SPACING if self.kind == "translate" else WAYPOINT_ANGLE
        return math.ceil(abs(self.amount) / limit - _TOL)

    def delta(self) -> tuple[np.ndarray, float]:
        """Tip displacement (m, shape (3,)) and yaw change (rad) of the whole segment."""
        d = np.zeros(3)
        if self.kind == "translate":
            d[_AXES[self.axis]] = self.amount
            return d, 0.0
        return d, self.amount


@dataclass(frozen=True)
class Motion:
    """A named motion of SPEC §2 with its real-robot figures.

    ``level`` is the contact-complexity level it is used at (1 or 2; ``None`` for the out-of-distribution
    motions), ``effector`` the effector it is tied to (``None`` if any), ``duration`` the real duration (s),
    ``n_waypoints`` the real planner's waypoint count and ``sim_steps`` the expected number of simulation
    steps (= :attr:`Trajectory.n_steps`) at dt = 0.01 s.
    """

    name: str
    level: int | None
    effector: str | None
    segments: tuple[Segment, ...]
    duration: float
    n_waypoints: int
    sim_steps: int

    def end_offset(self) -> tuple[np.ndarray, float]:
        """Tip displacement (m, (3,)) and yaw (rad) at the end, relative to the start."""
        pos, yaw = np.zeros(3), 0.0
        for seg in self.segments:
            d, r = seg.delta()
            pos, yaw = pos + d, yaw + r
        return pos, yaw


def _t(axis: str, amount: float) -> Segment:
    return Segment("translate", axis, amount)


_D = 0.025
MOTIONS: dict[str, Motion] = {m.name: m for m in (
    Motion("poking-1", 1, None, (_t("z", -0.015), _t("z", 0.03)), 0.86, 38, 87),
    Motion("poking-2", 1, None, (_t("z", -0.02), _t("z", 0.03)), 0.93, 40, 94),
    Motion("poking-shifting-1", 2, None, (_t("z", -0.02), _t("x", -0.03), _t("z", 0.03)), 1.52, 68, 152),
    Motion("poking-shifting-2", 2, None, (_t("z", -0.02), _t("x", 0.03), _t("z", 0.03)), 1.50, 54, 153),
    Motion("flattening", None, "cylinder",
           (_t("z", -_D), _t("x", _D), _t("z", _D), _t("x", -_D), _t("z", -_D), _t("x", -_D), _t("z", _D)),
           3.74, 275, 378),
    Motion("triple-poking", None, "round",
           (_t("y", _D), _t("z", -_D), _t("z", _D), _t("y", -_D), _t("z", -_D), _t("z", _D),
            _t("y", -_D), _t("z", -_D), _t("z", _D)),
           4.55, 328, 460),
    Motion("poking-180-rotating", None, "rectangle",
           (_t("z", -_D), Segment("rotate", "z", math.pi), _t("z", _D)), 6.23, 504, 625),
)}
"""The seven motions of SPEC §2 by name."""


def get_motion(name: str) -> Motion:
    """The motion called ``name``; ``KeyError`` listing the known names otherwise."""
    try:
        return MOTIONS[name]
    except KeyError:
        raise KeyError(f"unknown motion {name!r}; known motions are {sorted(MOTIONS)}") from None


def check_effector(motion: str, effector: str, kind: str | None) -> None:
    """``ValueError`` if ``motion`` is made with one effector (SPEC §2: the out-of-distribution motions) and the
    effector called ``effector``, of built-in ``kind`` (None for a dataset's own mesh effector, which may
    stand for any), is another."""
    tied = get_motion(motion).effector
    if tied is not None and kind not in (None, tied):
        raise ValueError(f"motion {motion} is made with the {tied} effector (SPEC §2), not {effector}")


@dataclass(frozen=True)
class Waypoints:
    """Planner output: time stamps ``t`` (n,) in s (strictly increasing), tip positions ``xyz`` (n, 3) in m
    and yaw ``yaw`` (n,) in rad, all in the robot base frame."""

    t: np.ndarray
    xyz: np.ndarray
    yaw: np.ndarray

    def __post_init__(self):
        t, xyz, yaw = (np.asarray(a, dtype=float) for a in (self.t, self.xyz, self.yaw))
        n = len(t)
        if t.ndim != 1 or xyz.shape != (n, 3) or yaw.shape != (n,):
            raise ValueError(f"waypoint shapes disagree: t {t.shape}, xyz {xyz.shape}, yaw {yaw.shape}")
        if n < 2:
            raise ValueError(f"need at least 2 waypoints, got {n}")
        if not (np.isfinite(t).all() and np.isfinite(xyz).all() and np.isfinite(yaw).all()):
            raise ValueError("waypoints contain non-finite values")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise ValueError(f"time stamps must increase strictly; t[{bad[0] + 1}]={t[bad[0] + 1]} "
                             f"does not exceed t[{bad[0]}]={t[bad[0]]}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "xyz", xyz)
        object.__setattr__(self, "yaw", yaw)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


@dataclass(frozen=True)
class Trajectory:
    """Effector tip trajectory at a constant step: ``positions`` (n_steps+1, 3) offsets from the start (m),
    ``yaw`` (n_steps+1,) rotation about z relative to the start (rad), step ``dt`` (s).
    Row 0 is the start (zeros); row k is the pose after step k."""

    positions: np.ndarray
    yaw: np.ndarray
    dt: float = DT

    @property
    def n_steps(self) -> int:
        """Number of simulation steps (the SPEC's "sim steps")."""
        return len(self.positions) - 1

    def velocities(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-step tip velocity (n_steps, 3) in m/s and yaw rate (n_steps,) in rad/s."""
        return np.diff(self.positions, axis=0) / self.dt, np.diff(self.yaw) / self.dt


def resample(waypoints: Waypoints, dt: float = DT) -> Trajectory:
    """Resample planner waypoints to a constant step ``dt`` (s) by the rule in the module docstring;
    positions and yaw become offsets from the first waypoint."""
    if not dt > 0:
        raise ValueError(f"dt must be positive, not {dt}")
    pos = [np.zeros((1, 3))]
    yaw = [np.zeros(1)]
    p0, y0 = waypoints.xyz[0], waypoints.yaw[0]
    for j, d in enumerate(np.diff(waypoints.t)):
        n = max(1, math.ceil(d / dt - _TOL))
        frac = np.minimum(np.arange(1, n + 1) * dt / d, 1.0)[:, None]
        frac[-1] = 1.0
        a, b = waypoints.xyz[j] - p0, waypoints.xyz[j + 1] - p0
        ya, yb = waypoints.yaw[j] - y0, waypoints.yaw[j + 1] - y0
        pos.append(a + frac * (b - a))
        yaw.append(ya + frac[:, 0] * (yb - ya))
    return Trajectory(np.concatenate(pos), np.concatenate(yaw), dt)


def _apportion(total: int, weights: np.ndarray, minimum: np.ndarray) -> np.ndarray:
    """Integers ≥ ``minimum`` summing to ``total``, roughly proportional to ``weights`` (largest remainder)."""
    ideal = total * weights / weights.sum()
    out = np.maximum(minimum, np.floor(ideal).astype(int))
    while out.sum() != total:
        gap = ideal - out
        if out.sum() < total:
            out[np.argmax(gap)] += 1
        else:
            gap[out <= minimum] = np.inf
            out[np.argmin(gap)] -= 1
    return out


def plan(motion: Motion, seed: int = 0, start_xyz=(0.0, 0.0, 0.0), start_yaw: float = 0.0) -> Waypoints:
    """Synthetic planner output for ``motion``: exactly ``motion.n_waypoints`` waypoints, at most 0.002 m
    or 5° apart, denser where each segment starts and stops, with uneven time stamps starting at 0 and
    summing to ``motion.duration``. Deterministic from ``seed``.

    The time stamps stand in for those of the real planner: interval j lasts (k_j − f_j)·dt with integer
    k_j ≥ 1 and a fraction 0 ≤ f_j < 1, and Σ f_j = ``sim_steps`` − duration/dt, as the real recordings
    imply. :func:`resample` then yields Σ k_j = ``sim_steps`` steps."""
    rng = np.random.default_rng(seed)
    segs = motion.segments
    minimum = np.array([s.min_intervals() for s in segs])
    if minimum.sum() > motion.n_waypoints - 1:
        raise ValueError(f"motion {motion.name}: {motion.n_waypoints} waypoints cannot keep 0.002 m / 5° spacing")
    per_seg = _apportion(motion.n_waypoints - 1, minimum * rng.uniform(0.8, 1.2, len(segs)), minimum)

    xyz, yaw, lengths = [np.asarray(start_xyz, float)], [float(start_yaw)], []
    for seg, m in zip(segs, per_seg):
        # Ease-in/out spacing: u(s) = s − c·sin(2πs)/(2π) has slope 1 ± c, so the largest step is (1+c)/m.
        c = min(0.6, max(0.0, m / seg.min_intervals() - 1.0)) * rng.uniform(0.5, 1.0)
        s = np.arange(1, m + 1) / m
        u = s - c * np.sin(2 * np.pi * s) / (2 * np.pi)
        d, r = seg.delta()
        prev = 0.0
        for uk in u:
            xyz.append(xyz[-1] + (uk - prev) * d)
            yaw.append(yaw[-1] + (uk - prev) * r)
            lengths.append((uk - prev) * (np.abs(d).sum() / WAYPOINT_SPACING + abs(r) / WAYPOINT_ANGLE))
            prev = uk

    n_int = motion.n_waypoints - 1
    excess = motion.sim_steps - round(motion.duration / DT, 9)
    if not 0 <= excess < n_int or motion.sim_steps < n_int:
        raise ValueError(f"motion {motion.name}: {motion.sim_steps} steps are inconsistent with "
                         f"{motion.duration} s over {n_int} waypoint intervals")
    k = _apportion(motion.sim_steps, np.asarray(lengths) * rng.uniform(0.6, 1.4, n_int), np.ones(n_int, int))
    w = rng.uniform(0.5, 1.5, n_int)
    f = excess * w / w.sum()
    t = np.concatenate([[0.0], np.cumsum((k - f) * DT)])
    t[-1] = motion.duration
    return Waypoints(t, np.array(xyz), np.array(yaw))


def trajectory(name: str, seed: int = 0) -> Trajectory:
    """The resampled synthetic-planner trajectory of the motion called ``name``."""
    return resample(plan(get_motion(name), seed))


_COLUMNS = ["t", "x", "y", "z", "yaw"]


def read_waypoints(path: str | os.PathLike) -> Waypoints:
    """Read a planner trajectory CSV with columns t,x,y,z,yaw (s, m, m, m, rad).
    Raises ``ValueError`` naming the file if it is missing columns, non-numeric, non-finite,
    shorter than 2 rows or not strictly increasing in time."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: planner trajectory file not found")
    df = read_csv(path)
    missing = [c for c in _COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {_COLUMNS}")
    try:
        a = df[_COLUMNS].to_numpy(dtype=float)
    except ValueError as e:
        raise ValueError(f"{path}: non-numeric value ({e})") from None
    try:
        return Waypoints(a[:, 0], a[:, 1:4], a[:, 4])
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def write_waypoints(path: str | os.PathLike, waypoints: Waypoints) -> None:
    """Write ``waypoints`` as a CSV with columns t,x,y,z,yaw, atomically (temp file + rename)."""
    df = pd.DataFrame(np.column_stack([waypoints.t, waypoints.xyz, waypoints.yaw]), columns=_COLUMNS)
    with atomic_output(path) as tmp:
        df.to_csv(tmp, index=False, float_format="%.17g")


__all__ = [
    "DT", "WAYPOINT_SPACING", "WAYPOINT_ANGLE", "Segment", "Motion", "MOTIONS", "get_motion", "check_effector",
    "Waypoints", "Trajectory", "resample", "plan", "trajectory", "read_waypoints", "write_waypoints",
]
