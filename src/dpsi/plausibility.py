"""Is a prepared datapoint a physically possible capture? Checks made before anything is simulated, shared by
the command line and the workflow's prepare stage, on what the simulation will see: the before particles,
the after state's PCD target (its surface points), the effector's tip path and the table.

An *error* is a capture that cannot have happened (the clay floats, is buried in the table, was moved
away, the tool never touched it or started inside it, or moved faster than a robot moves a tool); a
*warning* is one that is suspicious but possible. Tolerances (lengths in m, speeds in m/s):

- :data:`CALIBRATION` (3 mm, SPEC §3.1 / the paper: fused views disagree by about ±3 mm) is what a
  captured shape may be off; half a particle (the lattice puts its cubes within half a spacing of the
  mesh's top and bottom) is added wherever particles are compared with a surface.
- :data:`IMPOSSIBLE_GAP` (10 mm, three calibration errors): a lump whose bottom is this far above the
  table does not rest on it (closer, but beyond the calibration error, is a warning: it would fall that far
  first); an after shape this much taller than the before shape was not pressed from above (the motions
  of SPEC §2 push down and sideways). A bottom below the table by more than the calibration error is an
  error: no clay can be inside the table.
- The after shape's footprint (bounding box in x, y) must overlap the before shape's (an error if they
  share nothing: the tool moves 5 cm sideways at most, and clay sticks to the table), and its centre should
  not have moved further than the tool moves sideways plus :data:`IMPOSSIBLE_GAP` (a warning: clay moves
  with the tool, but a spreading shape shifts its centre too).
- The tip must reach the object (some step puts it below the object's top under its footprint) and must
  not start inside it by more than the calibration error.
- Tip speed: the motions of SPEC §2, as planned, never exceed 0.12 m/s; above :data:`SUSPICIOUS_SPEED`
  (0.3 m/s) is a warning, above :data:`IMPOSSIBLE_SPEED` (1 m/s, eight times that: a jump, not a robot's
  motion pressing clay) an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dpsi.datapoint import Datapoint

CALIBRATION = 0.003
"""Error (m) of a captured shape: the disagreement of fused camera views (SPEC §3.1)."""

IMPOSSIBLE_GAP = 0.010
"""Gap (m) between the before shape and the table, or rise of the after shape's top, beyond which the
capture cannot be right."""

SUSPICIOUS_SPEED = 0.3
"""Tip speed (m/s) above which a trajectory is suspicious: 2.5 × the fastest planned motion of SPEC §2."""

IMPOSSIBLE_SPEED = 1.0
"""Tip speed (m/s) above which a trajectory is not a robot's motion pressing clay."""

CENTRE_RADIUS = 0.005
"""Radius (m) around the tip's axis within which the object must not stand above the tip at the start (the
effectors' lowest parts lie within it: the bullet's tip, the roller's line, the flat faces)."""


class ImplausibleInput(ValueError):
    """A datapoint no real capture can give; the message lists every reason, naming the shapes."""


@dataclass
class Findings:
    """What the checks found: ``errors`` (impossible) and ``warnings`` (suspicious), as messages."""

    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def add(self, message: str, impossible: bool) -> None:
        (self.errors if impossible else self.warnings).append(message)


def _mm(length: float) -> str:
    return f"{length * 1e3:.1f} mm"


def _resting(dp: Datapoint, before: str, table: str, found: Findings) -> None:
    """The before shape's bottom (its lowest particle cube) on the table."""
    half = dp.particle_size / 2
    gap = float(dp.particles[:, 2].min() - half - dp.table_z)
    if abs(gap) > CALIBRATION + half:
        where = "above" if gap > 0 else "below"
        what = "it would fall" if gap > 0 else "it is sunk into the table"
        found.add(f"{before}: its bottom is {_mm(abs(gap))} {where} the table (z = {dp.table_z:g} m): {what}; a "
                  f"lump resting on the table is within {_mm(CALIBRATION)} of it (check {table}, or the shape's "
                  "frame)", gap < 0 or gap > IMPOSSIBLE_GAP + half)


def _footprint(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points[:, :2].min(axis=0), points[:, :2].max(axis=0)


def _after_shape(dp: Datapoint, before: str, after: str, found: Findings) -> None:
    """The after shape on the before shape's footprint, not moved further than the tool, and not taller."""
    (blo, bhi), (alo, ahi) = _footprint(dp.particles), _footprint(dp.pcd_target)
    shift = (alo + ahi) / 2 - (blo + bhi) / 2
    travel = np.ptp(dp.trajectory.positions[:, :2], axis=0)
    if (np.minimum(bhi, ahi) <= np.maximum(blo, alo)).any():
        found.add(f"{after}: its footprint does not overlap {before}'s (centres {_mm(np.linalg.norm(shift))} apart); "
                  "the motions move the clay a few centimetres at most, so both shapes must be in one frame (robot "
                  "base, metres)", impossible=True)
    elif (np.abs(shift) > travel + IMPOSSIBLE_GAP).any():
        found.add(f"{after}: its footprint's centre lies {_mm(np.linalg.norm(shift))} from {before}'s (x "
                  f"{_mm(shift[0])}, y {_mm(shift[1])}), more than the tool moves sideways ({_mm(travel[0])} in x, "
                  f"{_mm(travel[1])} in y) plus {_mm(IMPOSSIBLE_GAP)}; are both shapes in one frame?", impossible=False)
    rise = float(dp.pcd_target[:, 2].max() - (dp.particles[:, 2].max() + dp.particle_size / 2))
    if rise > CALIBRATION + dp.particle_size / 2:
        found.add(f"{after}: its top is {_mm(rise)} higher than the top of {before}; the motions press the clay "
                  "down — are before and after swapped?", rise > IMPOSSIBLE_GAP + dp.particle_size / 2)


def _under_tip(dp: Datapoint, tip: np.ndarray, radius: float) -> float:
    """Height (m) of the object's top (particle cubes) above the tip within ``radius`` m of its axis; −inf
    where nothing is under it."""
    near = np.hypot(*(dp.particles[:, :2] - tip[:2]).T) <= radius
    if not near.any():
        return -np.inf
    return float(dp.particles[near, 2].max() + dp.particle_size / 2 - tip[2])


def _effector_path(dp: Datapoint, path: str, before: str, found: Findings) -> None:
    """The tip reaches the object, does not start inside it, and moves at a robot's speed."""
    tips = dp.start + dp.trajectory.positions
    corner = np.maximum(np.abs(dp.effector.bounds[0][:2]), np.abs(dp.effector.bounds[1][:2]))
    reach = float(np.hypot(*corner))  # the effector's footprint at any yaw lies within this radius
    deepest = max(_under_tip(dp, tip, reach) for tip in tips)
    if deepest <= 0:
        clearance = "nothing of it lies under the effector" if deepest == -np.inf else \
            f"the effector stays {_mm(-deepest)} above it"
        found.add(f"{path}: the effector never reaches {before} ({clearance}); the tip starts at "
                  f"{np.round(dp.start, 4).tolist()} m and moves {_mm(np.ptp(tips, axis=0).max())} at most",
                  impossible=True)
    inside = _under_tip(dp, tips[0], max(CENTRE_RADIUS, dp.particle_size))
    if inside > CALIBRATION + dp.particle_size / 2:
        found.add(f"{path}: the tip starts {_mm(inside)} inside {before} (at {np.round(dp.start, 4).tolist()} m, "
                  "below the object's top there); a motion starts above the object", impossible=True)
    speeds = np.linalg.norm(np.diff(tips, axis=0), axis=1) / dp.trajectory.dt
    if len(speeds) and speeds.max() > SUSPICIOUS_SPEED:
        k = int(np.argmax(speeds))
        found.add(f"{path}: the tip moves at {speeds[k]:.2f} m/s in step {k + 1} ({_mm(speeds[k] * dp.trajectory.dt)}"
                  f" in {dp.trajectory.dt:g} s); planned motions stay below {SUSPICIOUS_SPEED:g} m/s, and faster "
                  f"than {IMPOSSIBLE_SPEED:g} m/s is a jump, not a robot's motion", speeds[k] > IMPOSSIBLE_SPEED)


def findings(dp: Datapoint, before: str = "the before shape", after: str = "the after shape",
             path: str = "the effector path", table: str = "the table height") -> Findings:
    """Every error and warning of the checks (module doc) on ``dp``; ``before``, ``after`` and ``path`` name
    the shapes and the trajectory in the messages, ``table`` where the table height is set."""
    found = Findings()
    _resting(dp, before, table, found)
    _after_shape(dp, before, after, found)
    _effector_path(dp, path, before, found)
    return found


def check_plausible(dp: Datapoint, before: str = "the before shape", after: str = "the after shape",
                    path: str = "the effector path", table: str = "the table height") -> list[str]:
    """The warnings of :func:`findings`; :class:`ImplausibleInput` listing every error if there is one."""
    found = findings(dp, before, after, path, table)
    if found.errors:
        raise ImplausibleInput("; ".join(found.errors) if len(found.errors) == 1 else
                               f"{len(found.errors)} problems: " + "; ".join(found.errors))
    return found.warnings


__all__ = ["CALIBRATION", "IMPOSSIBLE_GAP", "SUSPICIOUS_SPEED", "IMPOSSIBLE_SPEED", "CENTRE_RADIUS",
           "ImplausibleInput", "Findings", "findings", "check_plausible"]
