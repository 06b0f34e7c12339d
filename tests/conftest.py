"""Shared fixtures: the tiny end-to-end workflow run, used by the workflow and the analysis tests."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile")]
TINY = ROOT / "tests" / "data" / "tiny.yaml"
SHARED = ROOT.parent / "shared"
"""The project's shared folder beside the clone (real clay meshes, measured effectors); CI has it."""


def shared(relative: str) -> Path:
    """``SHARED / relative``; if it is missing the test is skipped, saying why — or fails under CI (the
    environment variable CI set), where ../shared is always there."""
    path = SHARED / relative
    if not path.exists():
        reason = f"{path} not found: it comes with the project's shared folder beside this clone (../shared)"
        if os.environ.get("CI"):
            pytest.fail(reason + "; CI must provide it")
        pytest.skip(reason)
    return path


def snakemake(workdir, *args, config=TINY):
    """Run Snakemake on the project's Snakefile in ``workdir`` with ``config``."""
    return subprocess.run([*SNAKEMAKE, "--directory", str(workdir), "--configfile", str(config), *args],
                          capture_output=True, text=True)


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """`tables` and `figures` (the analyses included) on the tiny twin, every job submitted through the
    generic cluster executor, so that nothing can rely on shared process state. With the environment
    variable DPSI_TINY_RUN set to a folder, the run completes that folder instead of a new one (for working
    on one analysis without rerunning the rest)."""
    workdir = Path(os.environ["DPSI_TINY_RUN"]) if "DPSI_TINY_RUN" in os.environ else tmp_path_factory.mktemp("workflow")
    run = snakemake(workdir, "--executor", "cluster-generic", "--cluster-generic-submit-cmd", "bash",
                    "--jobs", "1", "--latency-wait", "5", "--seconds-between-status-checks", "1", "tables", "figures")
    assert run.returncode == 0, (run.stdout + run.stderr)[-4000:]
    return workdir
