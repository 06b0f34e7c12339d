"""Greedy planning towards a target height map with the identified simulator (SPEC §7.8, the paper's
appendix B).

Before every action the planner tries each candidate from the current state and keeps the one whose
simulated result has the smallest height-map distance (mm) to the target. The candidates are each
configured motion with the configured effector, its tip starting at the object's highest z above one of
grid × grid locations spaced ``spacing`` m apart in x and y and centred on the object's footprint, plus
the *empty action*, which leaves the object as it is (so a plan never makes the distance worse).

Between actions the next simulation starts from the particle positions alone, at rest and undeformed:
a real robot would re-capture the object and fill the new shape with particles, losing the stress and
deformation history, and the planner does the same.

Candidates the simulator rejects — the tip path leaves the simulated box, or the simulation goes
unstable (:class:`~dpsi.simulation.SimulationError`) — are skipped and recorded with the reason.
Lengths in m, height-map distances in mm, robot base frame.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dpsi.effectors import Effector
from dpsi.heightmap import footprint_centre, heightmap_distance_mm
from dpsi.losses import HeightMapTarget, simulated_heightmap
from dpsi.motions import Trajectory, trajectory
from dpsi.parameters import Parameters
from dpsi.progress import Progress
from dpsi.files import atomic_output
from dpsi.simulation import Scene, SimulationError, Simulator

EMPTY = "none"
"""Motion label of the empty action in records and tables."""

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Action:
    """A candidate action: ``motion`` (a name of :data:`dpsi.motions.MOTIONS`) with the effector tip
    starting at ``start`` (x, y, z) in m. Without a motion it is the empty action: nothing moves."""

    motion: str | None = None
    start: tuple[float, float, float] | None = None

    @property
    def label(self) -> str:
        """The motion's name, or :data:`EMPTY`."""
        return self.motion or EMPTY

    def as_dict(self) -> dict:
        return {"motion": self.label, "start": None if self.start is None else list(self.start)}

    @classmethod
    def from_dict(cls, record: dict) -> "Action":
        if record["motion"] == EMPTY:
            return EMPTY_ACTION
        return cls(record["motion"], tuple(map(float, record["start"])))


EMPTY_ACTION = Action()


@dataclass(frozen=True)
class ActionSet:
    """What the planner may do at every action: each of ``motions`` with ``effector`` started at
    ``grid`` × ``grid`` locations ``spacing`` m apart, or nothing."""

    motions: tuple[str, ...]
    effector: Effector
    grid: int = 3
    spacing: float = 0.03

    def __post_init__(self):
        if not self.motions:
            raise ValueError("the action set needs at least one motion")
        if int(self.grid) != self.grid or self.grid < 1:
            raise ValueError(f"grid must be a positive integer, not {self.grid}")
        if not self.spacing > 0:
            raise ValueError(f"spacing must be positive, not {self.spacing} m")


def start_locations(particles: np.ndarray, grid: int, spacing: float) -> np.ndarray:
    """Tip start positions (grid², 3) in m: a grid × grid square of points ``spacing`` m apart in x and
    y, centred on the footprint centre of ``particles`` (n, 3), all at the particles' highest z.
    Ordered with x varying slowest."""
    offsets = (np.arange(grid) - (grid - 1) / 2) * spacing
    x, y = np.meshgrid(*(footprint_centre(particles)[k] + offsets for k in range(2)), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, particles[:, 2].max())])


def candidates(particles: np.ndarray, actions: ActionSet) -> list[Action]:
    """The candidates from the state ``particles`` (n, 3) in m: the empty action first (it wins ties),
    then every motion at every start location."""
    starts = [tuple(map(float, s)) for s in start_locations(particles, actions.grid, actions.spacing)]
    return [EMPTY_ACTION] + [Action(motion, start) for motion in actions.motions for start in starts]


@dataclass
class Step:
    """One chosen action: the state after it (``particles`` (n, 3) m, ``heightmap`` m), its distance to
    the target (mm), how many candidates were tried and which were skipped, with the reason."""

    action: Action
    particles: np.ndarray
    heightmap: np.ndarray
    distance_mm: float
    tried: int
    skipped: list[tuple[Action, str]] = field(default_factory=list)


@dataclass
class Plan:
    """A greedy plan: the ``target``, the ``start`` particles (n, 3) in m and the chosen ``steps``."""

    target: HeightMapTarget
    start: np.ndarray
    steps: list[Step]

    @property
    def initial_heightmap(self) -> np.ndarray:
        return simulated_heightmap(self.start, self.target)

    @property
    def initial_distance_mm(self) -> float:
        return heightmap_distance_mm(self.initial_heightmap, self.target.heights)

    @property
    def final_distance_mm(self) -> float:
        return self.steps[-1].distance_mm


class Planner:
    """Greedy search with one simulator, fixed parameters θ and an action set. ``particle_volume`` (m³)
    is the volume of each particle, ``table_z`` (m) the table height."""

    def __init__(self, simulator: Simulator, params: Parameters, actions: ActionSet, particle_volume: float,
                 table_z: float):
        self.simulator, self.params, self.actions = simulator, params, actions
        self.particle_volume, self.table_z = particle_volume, table_z
        self._trajectories: dict[str, Trajectory] = {m: trajectory(m) for m in actions.motions}

    def outcome(self, particles: np.ndarray, action: Action) -> np.ndarray:
        """Particles (n, 3) in m after ``action`` from ``particles`` at rest; raises
        :class:`SimulationError` if the simulator rejects it."""
        if action.motion is None:
            return particles.copy()
        scene = Scene(particles, self.particle_volume, self.actions.effector, self._trajectories[action.motion],
                      np.asarray(action.start), self.table_z)
        return self.simulator.forward(scene, self.params, keep_substeps=False)

    def step(self, particles: np.ndarray, target: HeightMapTarget, number: int = 1) -> Step:
        """Try every candidate from ``particles`` and return the one closest to ``target`` (ties go to
        the earlier candidate, so the empty action wins them). ``number`` only labels the progress lines
        (on stderr)."""
        best, skipped = None, []
        options = candidates(particles, self.actions)
        with Progress(len(options), f"plan action {number}") as bar:
            for k, action in enumerate(options, 1):
                try:
                    after = self.outcome(particles, action)
                except SimulationError as err:
                    skipped.append((action, str(err)))
                    bar.update(k, f"{_describe(action)} skipped: {err}")
                    continue
                heights = simulated_heightmap(after, target)
                distance = heightmap_distance_mm(heights, target.heights)
                bar.update(k, f"{_describe(action)} → {distance:.1f} mm")
                if best is None or distance < best.distance_mm:
                    best = Step(action, after, heights, distance, len(options))
        best.skipped = skipped
        return best

    def plan(self, particles: np.ndarray, target: HeightMapTarget, n_actions: int) -> Plan:
        """Choose ``n_actions`` actions greedily from ``particles`` (n, 3) in m towards ``target``.

        Once the empty action is best, every later search would start from the same state and choose it
        again (the simulation is deterministic), so the remaining actions are empty without simulating."""
        if n_actions < 1:
            raise ValueError(f"a plan needs at least one action, not {n_actions}")
        start = np.asarray(particles, dtype=float)
        steps: list[Step] = []
        while len(steps) < n_actions:
            step = self.step(steps[-1].particles if steps else start, target, len(steps) + 1)
            steps.append(step)
            log.info("action %d: chose %s, %.1f mm", len(steps), _describe(step.action), step.distance_mm)
            if step.action == EMPTY_ACTION:
                steps += [step] * (n_actions - len(steps))
        return Plan(target, start, steps)


def _describe(action: Action) -> str:
    if action.start is None:
        return action.label
    x, y, z = np.asarray(action.start) * 1000.0
    return f"{action.label} from ({x:.1f}, {y:.1f}, {z:.1f}) mm"


def plan_record(plan: Plan) -> dict:
    """The plan as JSON-ready data: the height-map centre (m), distances (mm) before and after every
    action, the actions (start in m) and the candidates skipped at each."""
    return {
        "centre_xy": list(map(float, plan.target.centre_xy)),
        "initial_distance_mm": plan.initial_distance_mm,
        "final_distance_mm": plan.final_distance_mm,
        "actions": [{**s.action.as_dict(), "distance_mm": s.distance_mm, "candidates": s.tried,
                     "skipped": [{**a.as_dict(), "reason": reason} for a, reason in s.skipped]}
                    for s in plan.steps],
    }


def save_plan(json_path: str | os.PathLike, npz_path: str | os.PathLike, plan: Plan, **metadata) -> None:
    """Write ``plan`` atomically: :func:`plan_record` plus ``metadata`` as JSON, and the arrays (target,
    start particles, particles and height maps after every action; m) as .npz."""
    with atomic_output(json_path) as tmp:
        tmp.write_text(json.dumps({**metadata, **plan_record(plan)}, indent=1))
    arrays = {"target": plan.target.heights, "centre_xy": plan.target.centre_xy, "floor": plan.target.floor,
              "particle_size": plan.target.particle_size,
              "start": plan.start, "particles": np.array([s.particles for s in plan.steps]),
              "heightmaps": np.array([s.heightmap for s in plan.steps])}
    with atomic_output(npz_path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)


def load_plan(json_path: str | os.PathLike, npz_path: str | os.PathLike) -> tuple[Plan, dict]:
    """The plan written by :func:`save_plan` and its JSON record (with the metadata)."""
    record = json.loads(Path(json_path).read_text())
    with np.load(npz_path) as data:
        target = HeightMapTarget(data["target"], data["centre_xy"], float(data["floor"]), float(data["particle_size"]))
        steps = [Step(Action.from_dict(a), particles, heights, a["distance_mm"], a["candidates"],
                      [(Action.from_dict(s), s["reason"]) for s in a["skipped"]])
                 for a, particles, heights in zip(record["actions"], data["particles"], data["heightmaps"])]
        return Plan(target, data["start"], steps), record


__all__ = ["EMPTY", "Action", "EMPTY_ACTION", "ActionSet", "start_locations", "candidates",
           "Step", "Plan", "Planner", "plan_record", "save_plan", "load_plan"]
