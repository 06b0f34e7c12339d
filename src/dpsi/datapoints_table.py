"""The datapoints table ``datapoints.csv`` of a raw dataset (docs/raw-format.md): its columns, the rule
for datapoint ids and the check of every row. Light to import (pandas and the motion names only), so the
workflow validates the table when it parses, before any id becomes part of a file path."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping

import pandas as pd

from dpsi.csv_files import read_csv
from dpsi.motions import MOTIONS, check_effector

COLUMNS = ("id", "motion", "effector", "level", "role", "material")
ROLES = ("train", "validation", "ood")
ID_MAX_LENGTH = 100
"""Longest datapoint id (characters). Ids become parts of file names, and a file name may hold 255 bytes
(NAME_MAX of common file systems); the longest name the workflow makes of an id (a hidden temporary copy of
a provenance record, ``.<id>_before.npy.provenance.<random>.tmp.json``) adds about 45 characters."""
ID_RULE = (f"letters, digits, '_', '-' or '.', starting with a letter or digit (no path separators), at most "
           f"{ID_MAX_LENGTH} characters")
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


class TableError(ValueError):
    """The datapoints table is malformed; the message names the file, the line and the problem."""


def check_id(datapoint_id: str, where: str) -> str:
    """``datapoint_id`` if it is a safe file name (see :data:`ID_RULE`); otherwise :class:`TableError`
    naming ``where``."""
    if not isinstance(datapoint_id, str) or not _ID.match(datapoint_id) or len(datapoint_id) > ID_MAX_LENGTH:
        shown = repr(datapoint_id)
        if len(shown) > 60:
            shown = f"{shown[:40]}… ({len(datapoint_id)} characters)"
        raise TableError(f"{where}: id {shown} must be {ID_RULE}; rename the datapoint (and its folder)")
    return datapoint_id


def check_table(df: pd.DataFrame, path: str | os.PathLike,
                effectors: Mapping[str, str | None] | None = None) -> pd.DataFrame:
    """Check the datapoints table ``df`` (all strings) read from ``path``: its columns, and per row the id,
    motion, level, role and material; the effector too if ``effectors`` (name → built-in kind, or None
    for a mesh effector) is given. Returns ``df``; raises :class:`TableError` naming the line."""
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise TableError(f"{path}: missing column(s) {missing}; expected {list(COLUMNS)}")
    if df.empty:
        raise TableError(f"{path}: has no datapoints")
    for line, r in enumerate(df[list(COLUMNS)].itertuples(index=False), start=2):
        where = f"{path}: line {line}"
        check_id(r.id, where)
        if r.motion not in MOTIONS:
            raise TableError(f"{where}: unknown motion {r.motion!r}; known motions are {sorted(MOTIONS)}")
        if effectors is not None:
            if r.effector not in effectors:
                raise TableError(f"{where}: unknown effector {r.effector!r}; known effectors are {sorted(effectors)}")
            try:
                check_effector(r.motion, r.effector, effectors[r.effector])
            except ValueError as e:
                raise TableError(f"{where}: {e}") from None
        if r.level not in ("1", "2"):
            raise TableError(f"{where}: level must be 1 or 2, not {r.level!r}")
        expected = MOTIONS[r.motion].level
        if expected is not None and int(r.level) != expected:
            raise TableError(f"{where}: motion {r.motion} belongs to level {expected}, not {r.level}")
        if r.role not in ROLES:
            raise TableError(f"{where}: role must be one of {list(ROLES)}, not {r.role!r}")
        if not str(r.material).strip():
            raise TableError(f"{where}: material is empty")
    duplicated = sorted(set(df["id"][df["id"].duplicated()]))
    if duplicated:
        raise TableError(f"{path}: duplicate datapoint id(s) {duplicated}")
    return df


def read_table(path: str | os.PathLike, effectors: Mapping[str, str | None] | None = None) -> pd.DataFrame:
    """The datapoints table at ``path`` as strings, checked by :func:`check_table`."""
    if not os.path.isfile(path):
        raise TableError(f"{path}: datapoints table not found")
    try:
        df = read_csv(path, dtype=str, keep_default_na=False)
    except ValueError as e:
        raise TableError(str(e)) from None
    return check_table(df, path, effectors)


__all__ = ["COLUMNS", "ROLES", "ID_MAX_LENGTH", "ID_RULE", "TableError", "check_id", "check_table", "read_table"]
