"""``dataset.yaml`` of a raw dataset (docs/raw-format.md): the table height, the workspace box and the
dataset's own effectors, read and checked. Light to import (yaml, numpy and the effector descriptions),
so that the workflow checks it while it parses, before a rule depends on a file named in it.

Every error names the file and the key. Files named in it (effector meshes) must be relative paths that
stay inside the dataset folder, and must exist; their contents are checked by :mod:`dpsi.rawdata`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from dpsi.effectors import BUILT_IN, Effector, by_name, effector_from_mesh

FILE = "dataset.yaml"
KEYS = ("table_z", "workspace", "effectors")
EFFECTOR_KINDS = tuple(BUILT_IN)


class DatasetYamlError(ValueError):
    """``dataset.yaml`` is malformed; the message names the file and the key."""


@dataclass(frozen=True)
class EffectorSpec:
    """An effector of the dataset: a built-in ``kind`` (rectangle/round/cylinder) or a mesh file ``obj``."""

    name: str
    kind: str | None = None
    obj: Path | None = None

    def effector(self) -> Effector:
        """The shape: the built-in one of ``kind`` under this name, or ``obj`` sampled into a signed-distance
        grid (tip at the mesh's origin)."""
        if self.obj is not None:
            return effector_from_mesh(self.obj, self.name)
        return dataclasses.replace(by_name(self.kind), name=self.name)


@dataclass(frozen=True)
class DatasetYaml:
    """What ``dataset.yaml`` says: ``table_z`` (m), the ``workspace`` box corners ((3,), (3,)) in m or
    ``None``, and the effectors by name (the built-ins and the dataset's own)."""

    table_z: float
    workspace: tuple[np.ndarray, np.ndarray] | None
    effectors: dict[str, EffectorSpec]

    def kinds(self) -> dict[str, str | None]:
        """Effector name → built-in kind (None for a mesh effector), as the datapoints table check takes it."""
        return {name: spec.kind for name, spec in self.effectors.items()}


def _load(path: Path) -> dict:
    try:
        cfg = yaml.safe_load(path.read_text())
    except yaml.constructor.ConstructorError as e:
        where = f" (line {e.problem_mark.line + 1})" if e.problem_mark else ""
        raise DatasetYamlError(f"{path}{where}: tags such as {e.problem.split()[-1] if e.problem else '!!python'} "
                               "are not allowed: the file holds plain numbers, lists and names only") from None
    except yaml.YAMLError as e:
        raise DatasetYamlError(f"{path}: not valid YAML ({e})") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetYamlError(f"{path}: cannot be read ({e})") from None
    if cfg is None:
        return {}
    if not isinstance(cfg, dict):
        raise DatasetYamlError(f"{path}: must be a mapping with the keys {list(KEYS)}, not a "
                               f"{type(cfg).__name__}")
    unknown = sorted(map(str, set(cfg) - set(KEYS)))
    if unknown:
        raise DatasetYamlError(f"{path}: unknown key(s) {unknown}; allowed: {list(KEYS)}")
    return cfg


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _workspace(path: Path, ws) -> tuple[np.ndarray, np.ndarray]:
    shape = "workspace must be {lo: [x, y, z], hi: [x, y, z]} in m"
    if not isinstance(ws, dict) or set(ws) != {"lo", "hi"}:
        raise DatasetYamlError(f"{path}: {shape}, not {ws!r}")
    for key in ("lo", "hi"):
        if not isinstance(ws[key], list) or len(ws[key]) != 3 or not all(map(_number, ws[key])):
            raise DatasetYamlError(f"{path}: workspace.{key} must be three numbers [x, y, z] in m, not {ws[key]!r}")
    lo, hi = np.asarray(ws["lo"], float), np.asarray(ws["hi"], float)
    if not (lo < hi).all():
        raise DatasetYamlError(f"{path}: workspace lo {lo.tolist()} must be below hi {hi.tolist()} in x, y and z")
    return lo, hi


def _inside(path: Path, key: str, relative) -> Path:
    """``relative`` (a path in ``dataset.yaml`` at ``key``) under the dataset folder, if it is a relative
    path staying inside it and an existing file."""
    root = path.parent
    if not isinstance(relative, str) or not relative.strip():
        raise DatasetYamlError(f"{path}: {key} must be a file name relative to the dataset folder, not {relative!r}")
    if Path(relative).is_absolute():
        raise DatasetYamlError(f"{path}: {key} is the absolute path {relative}; paths in {FILE} must be relative "
                               f"to the dataset folder {root}: copy the file into it and name it from there")
    file = root / relative
    if not file.resolve().is_relative_to(root.resolve()):
        raise DatasetYamlError(f"{path}: {key} {relative!r} leads outside the dataset folder {root}; paths in "
                               f"{FILE} must stay inside it: copy the file into it")
    if not file.is_file():
        raise DatasetYamlError(f"{path}: {key}: {file} not found")
    return file


def _effectors(path: Path, effectors) -> dict[str, EffectorSpec]:
    specs = {name: EffectorSpec(name, kind=name) for name in EFFECTOR_KINDS}
    if effectors is None:
        return specs
    if not isinstance(effectors, dict):
        raise DatasetYamlError(f"{path}: effectors must be a mapping {{name: {{kind: …}} or {{obj: <file>}}}}, "
                               f"not a {type(effectors).__name__}")
    for name, spec in effectors.items():
        if not isinstance(name, str):
            raise DatasetYamlError(f"{path}: effector name {name!r} must be text (quote it)")
        if not isinstance(spec, dict) or len(spec) != 1 or not {"kind", "obj"} & set(spec):
            raise DatasetYamlError(f"{path}: effectors.{name} needs exactly one of kind: {list(EFFECTOR_KINDS)} "
                                   "or obj: <file>")
        if "kind" in spec:
            if spec["kind"] not in EFFECTOR_KINDS:
                raise DatasetYamlError(f"{path}: effectors.{name} has unknown kind {spec['kind']!r}; use "
                                       f"{list(EFFECTOR_KINDS)}")
            specs[name] = EffectorSpec(name, kind=spec["kind"])
        else:
            specs[name] = EffectorSpec(name, obj=_inside(path, f"effectors.{name}.obj", spec["obj"]))
    return specs


def read_dataset_yaml(root: str | os.PathLike) -> DatasetYaml:
    """``root/dataset.yaml`` checked (defaults where it or a key is absent: table at z = 0, no workspace,
    the built-in effectors); :class:`DatasetYamlError` naming the file and the key otherwise."""
    path = Path(root) / FILE
    cfg = _load(path) if path.exists() else {}
    table_z = cfg.get("table_z", 0.0)
    if not _number(table_z):
        raise DatasetYamlError(f"{path}: table_z must be a number in m, not {table_z!r}")
    workspace = _workspace(path, cfg["workspace"]) if "workspace" in cfg else None
    return DatasetYaml(float(table_z), workspace, _effectors(path, cfg.get("effectors")))


__all__ = ["FILE", "KEYS", "EFFECTOR_KINDS", "DatasetYamlError", "EffectorSpec", "DatasetYaml", "read_dataset_yaml"]
