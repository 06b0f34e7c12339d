"""Shared fixtures: the tiny end-to-end workflow run, used by the workflow and the analysis tests."""

import fcntl
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


def leaves(value, path: str = "") -> dict:
    """The numbers and strings of a nested dict/list structure (a run summary, a log), keyed by their path
    (``best/parameters/E``)."""
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in leaves(item, f"{path}/{key}").items()}
    if isinstance(value, list):
        return {k: v for n, item in enumerate(value) for k, v in leaves(item, f"{path}/{n}").items()}
    return {path: value}


def assert_same_numbers(ran, expected, rel: float = 1e-12) -> None:
    """``ran`` and ``expected`` have the same structure, the same strings and integers, and the same floats up
    to ``rel``: two simulations of the same inputs differ in the last bit of a gradient, since the order of
    the simulator's parallel sums is not fixed."""
    ran, expected = leaves(ran), leaves(expected)
    assert ran.keys() == expected.keys()
    floats = [k for k, v in expected.items() if isinstance(v, float)]
    assert {k: v for k, v in ran.items() if k not in floats} == {k: v for k, v in expected.items() if k not in floats}
    assert [ran[k] for k in floats] == pytest.approx([expected[k] for k in floats], rel=rel, abs=rel, nan_ok=True)


LONGEST_FIRST = ("test_workflow", "test_real_workflow")
"""The test files that run whole workflows (the tiny twin's; the real clay's smoke), started first so that the
other workers are not left waiting for them at the end."""


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: (LONGEST_FIRST.index(item.module.__name__)
                                 if getattr(item, "module", None) and item.module.__name__ in LONGEST_FIRST
                                 else len(LONGEST_FIRST)))


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per core, at most four (each holds a simulator of up to a few GB)."""
    return max(1, min(4, os.cpu_count() or 1))


def snakemake(workdir, *args, config=TINY):
    """Run Snakemake on the project's Snakefile in ``workdir`` with ``config``."""
    return subprocess.run([*SNAKEMAKE, "--directory", str(workdir), "--configfile", str(config), *args],
                          capture_output=True, text=True)


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """`tables` and `figures` (the analyses included) on the tiny twin, every job submitted through the
    generic cluster executor, two at a time, so that nothing can rely on shared process state. Made once per test session:
    pytest-xdist's workers share it (the first to need it makes it, under a lock). With the environment
    variable DPSI_TINY_RUN set to a folder, the run completes that folder instead of a new one (for working
    on one analysis without rerunning the rest)."""
    if "DPSI_TINY_RUN" in os.environ:
        return _complete_tiny_run(Path(os.environ["DPSI_TINY_RUN"]))
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return _complete_tiny_run(tmp_path_factory.mktemp("workflow"))
    session = tmp_path_factory.getbasetemp().parent  # this session's folder, shared by its workers
    with open(session / "tiny-workflow.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        workdir, done = session / "tiny-workflow", session / "tiny-workflow.done"
        if not done.exists():
            workdir.mkdir(exist_ok=True)
            _complete_tiny_run(workdir)
            done.touch()
    return workdir


def _complete_tiny_run(workdir: Path) -> Path:
    run = snakemake(workdir, "--executor", "cluster-generic", "--cluster-generic-submit-cmd", "bash",
                    "--jobs", "2", "--latency-wait", "5", "--seconds-between-status-checks", "1", "tables", "figures")
    assert run.returncode == 0, (run.stdout + run.stderr)[-4000:]
    return workdir
