"""What a synthetic twin holds, without making it: the plan of its datapoints (:class:`Group`, :data:`Plan`),
the ground-truth parameters of its materials (:data:`MATERIALS`) and reading its ``truth.json``. The
workflow plans its jobs from here; :mod:`dpsi.twin` simulates and captures the datapoints.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from dpsi.datapoints_table import ROLES
from dpsi.datasets import EFFECTORS, LONG_MOTIONS, MOTION_A, MOTION_B
from dpsi.effectors import by_name
from dpsi.motions import get_motion
from dpsi.parameters import Parameters

MATERIALS = {
    "clay": Parameters(E=5e4, nu=0.3, rho=1200.0, yield_stress=2.5e3, mu_table=2.0, mu_effector=0.3),
    "slime": Parameters(E=1.2e4, nu=0.45, rho=1050.0, yield_stress=1.2e3, mu_table=0.3, mu_effector=0.5),
    "soil": Parameters(E=6e4, nu=0.3, rho=1600.0, yield_stress=3e3, mu_table=1.8, mu_effector=1.5),
}
"""Ground truth per material. Clay: away from the hand-picked literature values (so that the baseline is
not the answer), with the frictions that level 1 holds fixed (SPEC §1). Slime (cloud slime): softer
(E 12 kPa), nearly incompressible (ν 0.45), light (1050 kg/m³), yielding early (1.2 kPa) and slippery on
the table (0.3) but somewhat sticky on the effector (0.5). Soil (moist, compacted): stiffer (E 60 kPa),
compressible (ν 0.3), dense (1600 kg/m³), stronger (3 kPa) and strongly frictional (table 1.8,
effector 1.5)."""

TRUTH_FILE = "truth.json"

@dataclass(frozen=True)
class Group:
    """``count`` datapoints of each motion × effector, all of one ``material``, ``level`` and ``role``.
    ``effectors`` ``None`` means each motion's own effector (the long motions)."""

    material: str
    level: int
    role: str
    motions: tuple[str, ...]
    effectors: tuple[str, ...] | None = None
    count: int = 1

    def __post_init__(self):
        object.__setattr__(self, "motions", tuple(self.motions))
        if self.effectors is not None:
            object.__setattr__(self, "effectors", tuple(self.effectors))
            for e in self.effectors:
                by_name(e)
        if self.role not in ROLES:
            raise ValueError(f"group role must be one of {list(ROLES)}, not {self.role!r}")
        if self.level not in (1, 2):
            raise ValueError(f"group level must be 1 or 2, not {self.level!r}")
        if not isinstance(self.count, int) or self.count < 0:
            raise ValueError(f"group count must be a non-negative integer, not {self.count!r}")
        for name in self.motions:
            motion = get_motion(name)
            if motion.level not in (None, self.level):
                raise ValueError(f"motion {name} belongs to level {motion.level}, not {self.level}")
            if self.effectors is None and motion.effector is None:
                raise ValueError(f"motion {name} has no effector of its own: give the group's effectors")

    def rows(self) -> list[dict]:
        """Datapoints-table rows, ids ``<material>-<motion>-<effector>-<role>-<k>``."""
        return [dict(id=f"{self.material}-{m}-{e}-{self.role}-{k}", motion=m, effector=e, level=self.level,
                     role=self.role, material=self.material)
                for m in self.motions for e in (self.effectors or (get_motion(m).effector,))
                for k in range(self.count)]


Plan = tuple[Group, ...]
"""Which datapoints a twin has: a sequence of groups."""


def default_plan(train: int = 2, validation: int = 2, ood: int = 2, levels=(1, 2),
                 effectors=EFFECTORS, other_materials=("slime", "soil")) -> Plan:
    """The SPEC §6 datapoints: per level ``train`` clay datapoints of each motion × effector and
    ``validation`` of motion B per effector; ``ood`` of each long motion with its effector (level 2);
    for each of ``other_materials`` one poking-shifting-2 datapoint with the cylinder and one
    flattening datapoint to validate on."""
    groups = []
    for level in levels:
        groups += [Group("clay", level, "train", (MOTION_A[level], MOTION_B[level]), effectors, train),
                   Group("clay", level, "validation", (MOTION_B[level],), effectors, validation)]
    groups.append(Group("clay", 2, "ood", LONG_MOTIONS, None, ood))
    for material in other_materials:
        groups += [Group(material, 2, "train", ("poking-shifting-2",), ("cylinder",), 1),
                   Group(material, 2, "validation", ("flattening",), None, 1)]
    return tuple(g for g in groups if g.count > 0)


def plan_from_config(groups: list[dict]) -> Plan:
    """A plan from a list of mappings with the fields of :class:`Group` (e.g. read from YAML)."""
    try:
        return tuple(Group(**g) for g in groups)
    except TypeError as e:
        raise ValueError(f"bad twin plan group ({e}); fields are material, level, role, motions, effectors, "
                         "count") from None


def plan_rows(plan: Plan) -> list[dict]:
    """All datapoints-table rows of ``plan``; ``ValueError`` if two groups make the same id."""
    rows = [row for group in plan for row in group.rows()]
    ids = [r["id"] for r in rows]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise ValueError(f"twin plan makes duplicate datapoint id(s) {dup}; merge the groups")
    if not rows:
        raise ValueError("twin plan has no datapoints")
    return rows


def load_truth(root: str | os.PathLike) -> dict:
    """A twin's ``root/truth.json``: ``materials`` (:class:`Parameters` by material), ``seed``,
    ``simulator`` (settings of the twin's simulator), ``density`` (particles/m³) and ``motion_error`` (the
    settings of :class:`dpsi.twin.MotionError`; empty for none)."""
    path = Path(root) / TRUTH_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: twin truth file not found; run write_twin_table first")
    try:
        truth = json.loads(path.read_text())
        return {"materials": {m: Parameters.checked(**v) for m, v in truth["materials"].items()},
                "seed": int(truth["seed"]), "simulator": dict(truth["simulator"]),
                "density": float(truth["density"]),
                "motion_error": {k: float(v) for k, v in truth.get("motion_error", {}).items()}}
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: not a twin truth file ({e})") from None


__all__ = ["MATERIALS", "TRUTH_FILE", "Group", "Plan", "default_plan", "plan_from_config", "plan_rows", "load_truth"]
