"""The datasets of SPEC §6, selected from a datapoints table (:mod:`dpsi.datapoints_table`).

Per level, motion A is poking-1 / poking-shifting-1 and motion B poking-2 / poking-shifting-2:

- ``12-mix``: both motions × 3 effectors × the first 2 train datapoints of each combination;
- ``6-mix``: the same with the first 1;
- ``1-rectangle``, ``1-round``, ``1-cylinder``: the first train datapoint of motion B with that effector.

For datasets of any motions (real data, :mod:`dpsi.release`):

- ``pair-<id>``: the one train datapoint ``<id>``; ``pairs`` in a configuration stands for one such dataset
  per train datapoint of the level;
- ``mix``: every train datapoint of the level.

"First" means in table order. A level's validation set is its validation-role datapoints; a level without
any validates each dataset on the level's train datapoints left out of it (on the dataset itself if none is
left). The out-of-distribution set is the ood-role datapoints.
"""

from __future__ import annotations

import pandas as pd

from dpsi.datapoints_table import COLUMNS
from dpsi.motions import MOTIONS
DATASETS = ("12-mix", "6-mix", "1-rectangle", "1-round", "1-cylinder")
"""The datasets of SPEC §6."""
MIX, PAIR, PAIRS = "mix", "pair-", "pairs"
"""Datasets of any motions: all train datapoints of a level; one (``pair-<id>``); one per train datapoint."""
EFFECTORS = ("rectangle", "round", "cylinder")
MOTION_A = {1: "poking-1", 2: "poking-shifting-1"}
MOTION_B = {1: "poking-2", 2: "poking-shifting-2"}
LONG_MOTIONS = tuple(name for name, m in MOTIONS.items() if m.level is None)
"""The out-of-distribution motions, each made with its own effector."""


PLANNING_MOTION = "flattening"
"""The motion of the datapoint whose after state greedy planning aims at (SPEC §7.8)."""


def _frame(table) -> pd.DataFrame:
    """The table as strings, from a DataFrame or a loaded raw dataset (:class:`dpsi.rawdata.RawDataset`)."""
    if not isinstance(table, pd.DataFrame):
        table = pd.DataFrame([{c: getattr(d, c) for c in COLUMNS} for d in table.datapoints])
    missing = [c for c in COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"datapoints table lacks column(s) {missing}; expected {list(COLUMNS)}")
    return table[list(COLUMNS)].astype(str)


def _level(level: int) -> str:
    if level not in MOTION_A:
        raise ValueError(f"level must be 1 or 2, not {level!r}")
    return str(level)


def _recipe(level: int, name: str) -> list[tuple[str, str, int]]:
    """(motion, effector, how many) making up dataset ``name`` at ``level``."""
    if name in ("12-mix", "6-mix"):
        n = 2 if name == "12-mix" else 1
        return [(m[level], e, n) for m in (MOTION_A, MOTION_B) for e in EFFECTORS]
    if name.startswith("1-") and name[2:] in EFFECTORS:
        return [(MOTION_B[level], name[2:], 1)]
    raise ValueError(f"unknown dataset {name!r}; known datasets are {list(DATASETS)}, {MIX!r} and "
                     f"'{PAIR}<id>'")


def select(table: pd.DataFrame, level: int, name: str, material: str = "clay") -> list[str]:
    """Ids of the train datapoints forming dataset ``name`` (one of :data:`DATASETS`, :data:`MIX` or
    ``pair-<id>``) at ``level`` for ``material``; for the SPEC datasets in recipe order (motion A before B,
    effectors as in :data:`EFFECTORS`). Raises ``ValueError`` naming what is missing."""
    df = _frame(table)
    train = df[(df.level == _level(level)) & (df.role == "train") & (df.material == material)]
    if name == MIX or name.startswith(PAIR):
        ids = train.id.tolist() if name == MIX else [i for i in train.id if PAIR + i == name]
        if not ids:
            raise ValueError(f"dataset {name} (level {level}, {material}) has no train datapoint"
                             + ("" if name == MIX else f" {name[len(PAIR):]!r}"))
        return ids
    ids, missing = [], []
    for motion, effector, n in _recipe(level, name):
        found = train.id[(train.motion == motion) & (train.effector == effector)].tolist()
        if len(found) < n:
            missing.append(f"{n} of {motion} with {effector} (found {len(found)})")
        ids += found[:n]
    if missing:
        raise ValueError(f"dataset {name} (level {level}, {material}) lacks train datapoints: "
                         + "; ".join(missing))
    return ids


def expand_names(table: pd.DataFrame, level: int, names: list[str], material: str = "clay") -> list[str]:
    """The configured dataset ``names`` of ``level`` with :data:`PAIRS` replaced by ``pair-<id>`` for each
    train datapoint of the level, in table order."""
    df = _frame(table)
    train = df.id[(df.level == _level(level)) & (df.role == "train") & (df.material == material)]
    return [n for name in names for n in ([PAIR + i for i in train] if name == PAIRS else [name])]


def _role(table, role: str, material: str, level: int | None = None) -> list[str]:
    df = _frame(table)
    keep = (df.role == role) & (df.material == material)
    if level is not None:
        keep &= df.level == _level(level)
    ids = df.id[keep].tolist()
    if not ids:
        where = f" of level {level}" if level is not None else ""
        raise ValueError(f"the datapoints table has no {role} datapoints{where} for material {material!r}")
    return ids


def validation(table: pd.DataFrame, level: int, material: str = "clay", training: list[str] = ()) -> list[str]:
    """Ids of the validation datapoints of ``level`` and ``material``, in table order; if the level has
    none, its train datapoints not in ``training`` (the dataset's), or ``training`` itself if none is left."""
    df = _frame(table)
    at_level = df[(df.level == _level(level)) & (df.material == material)]
    if (at_level.role == "validation").any():
        return at_level.id[at_level.role == "validation"].tolist()
    left_out = [i for i in at_level.id[at_level.role == "train"] if i not in training]
    if not (left_out or training):
        raise ValueError(f"the datapoints table has no validation or train datapoints of level {level} for "
                         f"material {material!r}")
    return left_out or list(training)


def unseen(table: pd.DataFrame, training: list[str], material: str = "clay") -> list[str]:
    """Ids of the train and validation datapoints of ``material`` (either level) that are not in
    ``training``, in table order: where identified parameters are tried on data they did not see."""
    df = _frame(table)
    keep = df.role.isin(["train", "validation"]) & (df.material == material) & ~df.id.isin(list(training))
    return df.id[keep].tolist()


def ood(table: pd.DataFrame, material: str = "clay") -> list[str]:
    """Ids of the out-of-distribution (ood-role) datapoints of ``material``, in table order."""
    return _role(table, "ood", material)


def planning_start(table: pd.DataFrame) -> str:
    """Id of the first out-of-distribution clay datapoint of :data:`PLANNING_MOTION` in the datapoints
    table: its before state is the greedy plan's start, its captured after state the target.
    ``ValueError`` if there is none."""
    df = _frame(table)
    found = [i for i in ood(df) if df.set_index("id").motion[i] == PLANNING_MOTION]
    if not found:
        raise ValueError(f"planning needs an out-of-distribution clay datapoint of {PLANNING_MOTION}; "
                         "the datapoints table has none")
    return found[0]


__all__ = ["PLANNING_MOTION", "planning_start", "DATASETS", "MIX", "PAIR", "PAIRS", "expand_names", "unseen", "EFFECTORS", "MOTION_A", "MOTION_B", "LONG_MOTIONS", "select", "validation", "ood"]
