"""Provenance records: what produced a result file (config values, input checksums, package versions,
git commit), written beside it as ``<output>.provenance.json``."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import json
import logging
import subprocess
import sys
import traceback
from pathlib import Path

from .pointclouds import atomic_output

PACKAGES = ("dpsi", "taichi", "numpy", "scipy", "pandas", "open3d", "pymeshlab", "matplotlib", "snakemake")


def checksum(path: str | Path) -> str:
    """SHA-256 of a file, or of the relative names and contents of all files in a folder."""
    path = Path(path)
    digest = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for file in files:
        if path.is_dir():
            digest.update(str(file.relative_to(path)).encode())
        with open(file, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


@functools.cache
def library_checksum() -> str:
    """SHA-256 of the names and contents of the dpsi package's source files (``*.py``): the version of
    the library's code, which changes with any edit (computed once per process)."""
    package = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for file in sorted(package.rglob("*.py")):
        digest.update(str(file.relative_to(package)).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()


def package_versions() -> dict[str, str]:
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_commit(folder: str | Path = ".") -> str:
    """The commit checked out in ``folder`` (with "+changes" if the tree differs), or "unknown"."""
    try:
        run = lambda *args: subprocess.run(["git", *args], cwd=folder, capture_output=True, text=True,  # noqa: E731
                                           check=True).stdout.strip()
        return run("rev-parse", "HEAD") + ("+changes" if run("status", "--porcelain", "--untracked-files=no") else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def provenance_path(output: str | Path) -> Path:
    """The provenance record of ``output``: ``<output>.provenance.json``."""
    return Path(str(output).rstrip("/") + ".provenance.json")


def write_provenance(outputs, inputs, params: dict) -> None:
    """Write ``<output>.provenance.json`` beside each output (after the outputs exist)."""
    record = {"params": params, "inputs": {str(p): checksum(p) for p in inputs if Path(p).exists()},
              "packages": package_versions(), "git_commit": git_commit()}
    for output in outputs:
        with atomic_output(provenance_path(output)) as tmp:
            tmp.write_text(json.dumps(record, indent=1, default=str))


@contextlib.contextmanager
def recorded(outputs, inputs, params: dict, log_path: str | Path):
    """Run a stage with its messages (logging and stderr) going to ``log_path``; when it succeeds,
    write the provenance of its ``outputs``. Yields a logger.

    The provenance records of earlier outputs are removed first, so none outlives its output; if the
    stage fails, its error (message and traceback) is written to the log before it is raised again."""
    outputs = list(outputs)
    for output in outputs:
        provenance_path(output).unlink(missing_ok=True)
    with open(log_path, "w") as log, contextlib.redirect_stderr(log):
        logging.basicConfig(stream=log, level=logging.INFO, format="%(asctime)s %(message)s", force=True)
        try:
            yield logging.getLogger("dpsi")
        except BaseException:
            log.write(f"\nFAILED: {sys.exc_info()[1]}\n{traceback.format_exc()}")
            raise
        write_provenance(outputs, list(inputs), params)
