"""The published real clay data (the paper's data release) as a datapoints table, without reading a mesh.

The release keeps each datapoint's meshes as::

    data/<motion-folder>/<effector-folder>/[extra_data/|validation_data/]mesh_<i><0|1>_repaired[_normalised].obj

(``0`` before the motion, ``1`` after). ``../shared/real-clay`` holds a selection of them under other names,
with a ``MANIFEST.csv`` giving each file's published path; both layouts are read. Folders become motions,
levels and effectors by the tables given (:class:`ImportTables`, from the config's ``release`` section);
:mod:`dpsi.release` writes the raw dataset.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from dpsi.datapoints_table import check_id

MESH_NAME = re.compile(r"^mesh_(?P<index>\d+)(?P<state>[01])_repaired(?P<normalised>_normalised)?\.obj$")
"""A published mesh's file name: datapoint index, state (0 before, 1 after), and whether it was centred."""

SUBSETS = {"": "", "extra_data": "extra", "validation_data": "val"}
"""The release's sub-folders of an effector folder, and how a datapoint id marks them."""

class ReleaseError(ValueError):
    """The release folder or the import tables are not as expected; the message names what and where."""


@dataclass(frozen=True)
class PublishedPair:
    """One datapoint of the release: its folders, index, whether normalised, and its two mesh files."""

    motion_folder: str
    effector_folder: str
    subset: str
    index: int
    normalised: bool
    before: Path
    after: Path

    @property
    def published(self) -> str:
        """The pair's place in the release, for messages."""
        return "/".join(p for p in (self.motion_folder, self.effector_folder, self.subset) if p) + f" i={self.index}"


def _published_files(source: Path) -> dict[str, Path]:
    """Published path (``<motion>/<effector>/[subset/]<file>``, without ``data/``) → local file, from
    ``MANIFEST.csv`` if the folder has one, else by walking ``source`` (or ``source/data``)."""
    manifest = source / "MANIFEST.csv"
    if manifest.is_file():
        rows = pd.read_csv(manifest, dtype=str)
        if not {"local_path", "source_path"} <= set(rows.columns):
            raise ReleaseError(f"{manifest}: expected columns local_path and source_path")
        return {row.source_path.removeprefix("data/"): source / row.local_path
                for row in rows.itertuples() if row.source_path.startswith("data/")}
    root = source / "data" if (source / "data").is_dir() else source
    return {str(path.relative_to(root)): path for path in sorted(root.glob("*/*/**/mesh_*.obj"))}


def find_pairs(source: str | Path) -> list[PublishedPair]:
    """Every complete (before, after) pair under ``source`` (the release's root, its ``data`` folder, or a
    folder with a ``MANIFEST.csv``), sorted by place. :class:`ReleaseError` if there is none."""
    source = Path(source)
    if not source.is_dir():
        raise ReleaseError(f"{source}: the real data folder does not exist; point the import at a clone of the "
                           "data release (its root or its data/ folder) or at ../shared/real-clay")
    states: dict[tuple, dict[str, Path]] = {}
    for published, path in _published_files(source).items():
        parts = published.split("/")
        name = MESH_NAME.match(parts[-1])
        if name is None or len(parts) not in (3, 4) or (len(parts) == 4 and parts[2] not in SUBSETS):
            continue
        subset = parts[2] if len(parts) == 4 else ""
        key = (parts[0], parts[1], subset, int(name["index"]), bool(name["normalised"]))
        states.setdefault(key, {})[name["state"]] = path
    pairs = [PublishedPair(*key, found["0"], found["1"]) for key, found in sorted(states.items())
             if set(found) == {"0", "1"}]
    if not pairs:
        raise ReleaseError(f"{source}: no mesh pairs mesh_<i>0/1_repaired[_normalised].obj under "
                           "<motion-folder>/<effector-folder>/[extra_data/|validation_data/]")
    return pairs


def pair_id(pair: PublishedPair) -> str:
    """The datapoint id of a pair, e.g. ``poking-1-cylinder-extra5`` for
    ``data-motion-poking-1/eef-cylinder/extra_data`` i = 5."""
    motion = pair.motion_folder.removeprefix("data-motion-")
    effector = pair.effector_folder.removeprefix("eef-")
    return check_id(f"{motion}-{effector}-{SUBSETS[pair.subset]}{pair.index}", pair.published)


@dataclass(frozen=True)
class ImportTables:
    """How release folders become datapoints: motion folder → (SPEC motion, level), effector folder →
    effector name, and the role of datapoint ids that are not ``train`` (default)."""

    motions: Mapping[str, tuple[str, int]]
    effectors: Mapping[str, str]
    roles: Mapping[str, str]

    @classmethod
    def from_config(cls, section: Mapping) -> ImportTables:
        """From the config's ``release`` section: ``motions: {folder: {motion, level}}``, ``effectors:
        {folder: name}``, optional ``roles: {id: role}``."""
        motions = {folder: (spec["motion"], int(spec["level"])) for folder, spec in section["motions"].items()}
        return cls(motions, dict(section["effectors"]), dict(section.get("roles") or {}))




def plan_rows(source: str | Path, tables: ImportTables) -> list[tuple[dict, PublishedPair]]:
    """The datapoints table rows (id, motion, effector, level, role, material) of the pairs under ``source``
    whose folders ``tables`` names, each with its pair. :class:`ReleaseError` if there is none, or if
    ``tables.roles`` names an id that is not there."""
    planned = []
    for pair in find_pairs(source):
        if pair.motion_folder in tables.motions and pair.effector_folder in tables.effectors:
            motion, level = tables.motions[pair.motion_folder]
            datapoint = pair_id(pair)
            planned.append(({"id": datapoint, "motion": motion, "effector": tables.effectors[pair.effector_folder],
                             "level": level, "role": tables.roles.get(datapoint, "train"), "material": "clay"}, pair))
    if not planned:
        raise ReleaseError(f"{source}: none of its pairs lies in a folder named by the import tables "
                           f"(motions {sorted(tables.motions)}, effectors {sorted(tables.effectors)})")
    unknown = sorted(set(tables.roles) - {row["id"] for row, _ in planned})
    if unknown:
        raise ReleaseError(f"roles given for datapoints the release does not have: {unknown}; "
                           f"it has {[row['id'] for row, _ in planned]}")
    return planned


__all__ = ["MESH_NAME", "SUBSETS", "ReleaseError", "PublishedPair", "find_pairs", "pair_id", "ImportTables",
           "plan_rows"]
