"""The library's layers as the workflow sees them: parsing the workflow loads no simulator or geometry
library, and every rule depends on the library code its script imports (so a change reruns it)."""

import os
import re
import shutil
import subprocess
import sys

from conftest import ROOT, TINY

HEAVY = ("taichi", "open3d", "pymeshlab")


def test_what_the_workflow_parses_with_loads_no_simulator_or_geometry_library():
    rule_imports = set()
    for rules in (ROOT / "workflow" / "rules").glob("*.smk"):
        text = rules.read_text()
        for names in re.findall(r"^from dpsi import ([\w ,]+)", text, re.MULTILINE):
            rule_imports.update(name.split(" as ")[0].strip() for name in names.split(","))
        rule_imports.update(re.findall(r"^from dpsi\.(\w+) import", text, re.MULTILINE))
    assert {"datasets", "twin_plan", "datapoints_table"} <= rule_imports
    modules = sorted(f"dpsi.{m}" for m in rule_imports | {"motions", "parameters", "datasets", "datapoint", "files"})
    code = f"import sys, {', '.join(modules)}; print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), *sys.path])})
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]", f"{modules} load {run.stdout.strip()}"


def _snakemake(workdir, *args):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(workdir / "src"), *sys.path])}
    return subprocess.run([sys.executable, "-m", "snakemake", "--directory", str(workdir), "--configfile", str(TINY),
                           "--rerun-triggers", "mtime",
                           *args], cwd=workdir, capture_output=True, text=True, env=env)


def _jobs(dry_run: str) -> set[str]:
    return set(re.findall(r"^(?:local)?rule (\w+):", dry_run, re.MULTILINE))


def test_touching_a_module_identify_imports_reruns_identify(tmp_path):
    """A copy of the project whose every output exists, newer than the code: nothing to do (by modification
    times, the trigger that code inputs use). A module identification does not import (the cost table's)
    changes: the identify jobs stay; one that the identify script imports only through
    dpsi.identification (optim) changes: they and what follows are out of date, the stages before not."""
    for name in ("Snakefile", "workflow", "src", "config", "profiles"):
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy
        copy(ROOT / name, tmp_path / name)
    summary = _snakemake(tmp_path, "--summary", "tables")
    assert summary.returncode == 0, summary.stderr[-3000:]
    rows = [line.split("\t") for line in summary.stdout.splitlines()[1:] if "\t" in line]
    code_time, output_time = 1_000_000_000, 1_000_100_000
    for path in (tmp_path / "src").rglob("*.py"):
        os.utime(path, (code_time, code_time))
    for output, _, rule, *_ in rows:
        path = tmp_path / output
        if rule == "twin_datapoint":
            path.mkdir(parents=True, exist_ok=True)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.touch()
        os.utime(path, (output_time, output_time))
    assert _jobs(_snakemake(tmp_path, "-n", "tables").stdout) == set()

    os.utime(tmp_path / "src" / "dpsi" / "reporting" / "cost.py", (output_time + 10,) * 2)
    assert "identify" not in _jobs(_snakemake(tmp_path, "-n", "tables").stdout)
    os.utime(tmp_path / "src" / "dpsi" / "optim.py", (output_time + 20,) * 2)
    jobs = _jobs(_snakemake(tmp_path, "-n", "tables").stdout)
    assert {"identify", "identify_analysis", "make_tables"} <= jobs
    assert not {"twin_table", "targets", "prepare"} & jobs
