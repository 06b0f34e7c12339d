"""Shared fixtures: the tiny end-to-end workflow run, used by the workflow and the analysis tests."""

import fcntl
import os
import shlex
import subprocess
import sys
import time
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


LONGEST_FIRST = ("test_real_workflow",)
"""The test file that runs a whole workflow without the tiny run (the real clay's smoke), started first so that
the other workers are not left waiting for it at the end."""

TINY_RUN_FIRST = ("test_workflow",)
"""Of the test files that read the tiny run (collected last, see :func:`tiny_run`), those to start first."""


def _needs_tiny_run(item) -> bool:
    return "tiny_run" in getattr(item, "fixturenames", ())


def pytest_collection_modifyitems(items):
    """Orders the test files: the long whole-workflow file first, then the rest, and last the files that read
    the tiny run, so that the workers run everything else while the tiny run is being made; within a file the
    tests that do not read it come first. (pytest-xdist keeps this order only with --no-loadscope-reorder, as
    pyproject.toml sets it; by default it hands out the files with the most tests first.)"""
    late_files = {item.module.__name__ for item in items if _needs_tiny_run(item)}

    def rank(item):
        name = item.module.__name__ if getattr(item, "module", None) else ""
        if name in late_files:
            return 2 + (TINY_RUN_FIRST.index(name) if name in TINY_RUN_FIRST else len(TINY_RUN_FIRST)), name
        return (0 if name in LONGEST_FIRST else 1), ""
    items.sort(key=lambda item: (rank(item), _needs_tiny_run(item)))


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per core, at most four (each holds a simulator of up to a few GB)."""
    return max(1, min(4, os.cpu_count() or 1))


def snakemake_command(workdir, *args, config=TINY) -> list[str]:
    """The command line of Snakemake on the project's Snakefile in ``workdir`` with ``config``."""
    return [*SNAKEMAKE, "--directory", str(workdir), "--configfile", str(config), *args]


def snakemake(workdir, *args, config=TINY):
    """Run Snakemake on the project's Snakefile in ``workdir`` with ``config``."""
    return subprocess.run(snakemake_command(workdir, *args, config=config), capture_output=True, text=True)


TINY_RUN = ("--jobs", "2", "tables", "figures")
"""`tables` and `figures` (the analyses included) on the tiny twin, two jobs at a time."""


@pytest.fixture(scope="session", autouse=True)
def _tiny_run_in_background(request, tmp_path_factory):
    """The folder of this session's tiny run (None if no collected test reads it): started in the background as
    the session begins, by the first of pytest-xdist's workers (under a lock), so that the workers run the other
    tests meanwhile. Its worker waits for it at the end of the session."""
    if "DPSI_TINY_RUN" in os.environ or not any(_needs_tiny_run(item) for item in request.session.items):
        yield None
        return
    base = tmp_path_factory.getbasetemp()
    session = base.parent if "PYTEST_XDIST_WORKER" in os.environ else base  # shared by the workers
    workdir, process = session / "tiny-workflow", None
    with open(session / "tiny-workflow.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not workdir.exists():
            workdir.mkdir()
            # the exit status goes to a file of its own, written once the run has ended
            out = shlex.quote(str(workdir))
            script = (f"{shlex.join(snakemake_command(workdir, *TINY_RUN))} > {out}.log 2>&1; "
                      f"echo $? > {out}.rc.tmp && mv {out}.rc.tmp {out}.rc")
            process = subprocess.Popen(["bash", "-c", script])
    yield workdir
    if process is not None:
        process.wait()


@pytest.fixture(scope="session")
def tiny_run(_tiny_run_in_background):
    """The tiny twin's `tables` and `figures`, made once per test session (in the background from its start) and
    shared by the workers. Every job runs in a process of its own, as on a cluster; .ci/run then runs the
    workflow through SLURM for real. With the environment variable DPSI_TINY_RUN set to a folder, the run
    completes that folder instead (for working on one analysis without rerunning the rest)."""
    if "DPSI_TINY_RUN" in os.environ:
        workdir = Path(os.environ["DPSI_TINY_RUN"])
        run = snakemake(workdir, *TINY_RUN)
        assert run.returncode == 0, (run.stdout + run.stderr)[-4000:]
        return workdir
    workdir = _tiny_run_in_background
    status = Path(f"{workdir}.rc")
    while not status.exists():
        time.sleep(1)
    log = Path(f"{workdir}.log").read_text()
    assert status.read_text().strip() == "0", log[-4000:]
    return workdir
