"""The base layer of the library (numpy only): atomic writes, point-array checks, and "arrays + JSON
metadata" files (one ``.npz`` holding named arrays and a ``meta`` text entry with a JSON mapping).

Every writer of the library writes a temporary file in the target folder and renames it, so a failed
write never leaves a partial file.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike):
    """Yield a temporary path next to ``path`` (same suffix); on success rename it to ``path``,
    on any error delete it, so ``path`` is either complete or untouched."""
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"{path}: cannot write, folder {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; give it the usual permissions
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def check_points(points, source: str = "points", finite: bool = True) -> np.ndarray:
    """``points`` as a float (n, 3) array; ``ValueError`` naming ``source`` if empty, mis-shaped or (when
    ``finite``) non-finite."""
    a = np.asarray(points, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{source}: expected an (n, 3) array of points, got shape {a.shape}")
    if len(a) == 0:
        raise ValueError(f"{source}: contains no points")
    if finite and not np.isfinite(a).all():
        raise ValueError(f"{source}: contains non-finite coordinates")
    return a


def save_arrays(path: str | os.PathLike, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` and the JSON-serialisable mapping ``meta`` to ``path`` (.npz, compressed),
    atomically."""
    if "meta" in arrays:
        raise ValueError(f"{path}: 'meta' is reserved for the metadata, rename that array")
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, meta=json.dumps(dict(meta)), **arrays)


def load_arrays(path: str | os.PathLike, keys: Sequence[str], what: str,
                stage: str) -> tuple[dict, dict[str, np.ndarray]]:
    """``(meta, arrays)`` of a file written by :func:`save_arrays`, the arrays named in ``keys``; errors
    name the file, say it is not a (complete) ``what`` file and name the ``stage`` that makes it."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file {path} does not exist; run the stage that makes it ({stage}) first")
    try:
        with np.load(path, allow_pickle=False) as data:
            return json.loads(str(data["meta"])), {k: np.asarray(data[k]) for k in keys}
    except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as err:
        raise ValueError(f"{path} is not a complete {what} file ({err}): it is damaged, "
                         f"cut short or not made by this stage; delete it and rerun the stage that makes it "
                         f"({stage})") from err


__all__ = ["atomic_output", "check_points", "save_arrays", "load_arrays"]
