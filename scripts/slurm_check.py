#!/usr/bin/env python3
"""The checks of scripts/slurm-check.sh that read files and sacct (docs/cluster.md).

    slurm_check.py jobs --name RUN_ID [--state COMPLETED [--rule RULE]] [--json FILE]
        each job of a Snakemake SLURM run (the executor plugin names its jobs after the run's id) with its
        SLURM id, rule, state, elapsed time, CPU time and peak memory, from sacct; a summary per rule; exits
        1 unless every job (of --rule, of which there must be one) ended in --state
    slurm_check.py compare FOLDER_A FOLDER_B
        the tables (every tables/*.csv below each folder) of two runs of one configuration: equal, or equal
        to pytest.approx's default tolerance; measured figures (the cost table's timings) are left out
    slurm_check.py share --local CPU.json --slurm CPU.json --slurm-jobs JOBS.json
        Snakemake's own CPU time in a local and a SLURM run, as a share of each run's CPU time
    slurm_check.py bad-config IN OUT
        a copy of the configuration IN whose simulator refuses every datapoint (max_particles: 100)
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import yaml

REL_TOLERANCE = 1e-6
"""Relative tolerance of numbers in the tables: pytest.approx's default, which the tests use."""

MEASURED_COLUMNS = {
    "cost.csv": (re.compile(r".*_(s|min|mib)$|^taichi_cache$"),
                 "timings, memory peaks and the kernel cache's state are measurements of the run, not results"),
}
"""Per table, the columns that differ between runs by nature, and why."""

SACCT_FIELDS = ["JobID", "JobName", "Comment", "State", "ExitCode", "Elapsed", "TotalCPU", "MaxRSS",
                "AllocCPUS", "ReqMem", "Timelimit"]


# --- sacct ------------------------------------------------------------------------------------------------

def seconds(text: str) -> float:
    """Seconds of a SLURM duration: [D-]HH:MM:SS, MM:SS.mmm or HH:MM:SS.mmm ('' is 0)."""
    if not text:
        return 0.0
    days, _, clock = text.rpartition("-")
    parts = [float(p) for p in clock.split(":")]
    while len(parts) < 3:
        parts.insert(0, 0.0)
    hours, minutes, secs = parts
    return (int(days) if days else 0) * 86400 + hours * 3600 + minutes * 60 + secs


def mebibytes(text: str) -> float:
    """MiB of a SLURM memory figure such as 10736K, 1.5M, 2G or 512 (bytes); '' is 0."""
    if not text:
        return 0.0
    units = {"": 1 / 2**20, "K": 1 / 2**10, "M": 1.0, "G": 2**10, "T": 2**20}
    match = re.fullmatch(r"([0-9.]+)([KMGT]?)n?", text)
    if not match:
        raise ValueError(f"not a SLURM memory figure: {text!r}")
    return float(match[1]) * units[match[2]]


def rule_of(comment: str) -> str:
    """The rule a job ran, from the comment the executor plugin gives it (rule_<rule>[_wildcards_<...>])."""
    return comment.removeprefix("rule_").split("_wildcards_")[0] if comment.startswith("rule_") else "?"


def job_table(sacct_lines: list[str]) -> pd.DataFrame:
    """One row per job from `sacct -P -n -o <SACCT_FIELDS>` lines (a job and its steps): its id, rule,
    state, elapsed and CPU seconds (all steps), peak resident memory of its steps (MiB), CPUs and memory
    asked for, and time limit."""
    jobs, peaks = {}, {}
    for line in sacct_lines:
        if not line.strip():
            continue
        row = dict(zip(SACCT_FIELDS, line.split("|")))
        job_id, _, step = row["JobID"].partition(".")
        if step:
            peaks[job_id] = max(peaks.get(job_id, 0.0), mebibytes(row["MaxRSS"]))
        else:
            jobs[job_id] = row
    rows = [{
        "job_id": job_id,
        "rule": rule_of(row["Comment"]),
        "state": row["State"].split()[0],
        "exit_code": row["ExitCode"],
        "elapsed_s": seconds(row["Elapsed"]),
        "cpu_s": seconds(row["TotalCPU"]),
        "max_rss_mib": peaks.get(job_id, 0.0),
        "cpus": int(row["AllocCPUS"] or 0),
        "req_mem": row["ReqMem"],
        "time_limit": row["Timelimit"],
    } for job_id, row in jobs.items()]
    return pd.DataFrame(rows, columns=["job_id", "rule", "state", "exit_code", "elapsed_s", "cpu_s",
                                       "max_rss_mib", "cpus", "req_mem", "time_limit"])


def sacct_jobs(name: str) -> pd.DataFrame:
    """The jobs named ``name`` (every job of one Snakemake run) and their steps, from sacct."""
    out = subprocess.run(["sacct", "-a", "-P", "-n", "--starttime", "2000-01-01", "--name", name,
                          "-o", ",".join(SACCT_FIELDS)], check=True, capture_output=True, text=True).stdout
    return job_table(out.splitlines())


def rule_summary(jobs: pd.DataFrame) -> pd.DataFrame:
    """Per rule: jobs, mean and longest elapsed time, CPU time in all, and the largest peak memory."""
    return jobs.groupby("rule").agg(jobs=("job_id", "size"), elapsed_mean_s=("elapsed_s", "mean"),
                                    elapsed_max_s=("elapsed_s", "max"), cpu_total_s=("cpu_s", "sum"),
                                    max_rss_mib=("max_rss_mib", "max")).round(1)


def jobs_command(args) -> int:
    jobs = sacct_jobs(args.name)
    if jobs.empty:
        print(f"no job named {args.name} in sacct", file=sys.stderr)
        return 1
    with pd.option_context("display.max_rows", None, "display.width", 200):
        print(jobs.drop(columns=["exit_code"]).to_string(index=False))
        print()
        print(rule_summary(jobs).to_string())
    elapsed = jobs.elapsed_s.sum()
    print(f"\n{len(jobs)} jobs; elapsed {elapsed:.0f} s in all, CPU {jobs.cpu_s.sum():.0f} s, "
          f"largest peak memory {jobs.max_rss_mib.max():.0f} MiB; states: {jobs.state.value_counts().to_dict()}")
    if args.json:
        Path(args.json).write_text(jobs.to_json(orient="records", indent=1))
    if not args.state:
        return 0
    checked = jobs[jobs.rule == args.rule] if args.rule else jobs
    if checked.empty:
        print(f"no job of rule {args.rule} in the run", file=sys.stderr)
        return 1
    others = checked[checked.state != args.state]
    if len(others):
        print(f"jobs not {args.state}: {', '.join(others.job_id + ' ' + others.state)}", file=sys.stderr)
        return 1
    return 0


# --- tables -----------------------------------------------------------------------------------------------

def table_files(folder: Path) -> dict[str, Path]:
    """The CSV tables below ``folder`` (in any `tables` folder), by their path relative to it."""
    return {str(p.relative_to(folder)): p for p in sorted(folder.rglob("tables/*.csv"))}


def compare_table(a: Path, b: Path) -> str | None:
    """None if the tables ``a`` and ``b`` are equal (numbers to REL_TOLERANCE, the measured columns of
    MEASURED_COLUMNS left out), else what differs."""
    left, right = pd.read_csv(a), pd.read_csv(b)
    if list(left.columns) != list(right.columns) or left.shape != right.shape:
        return f"columns or shape differ: {list(left.columns)} {left.shape} against {list(right.columns)} {right.shape}"
    measured = MEASURED_COLUMNS.get(a.name)
    for column in left.columns:
        if measured and measured[0].match(column):
            continue
        x, y = left[column], right[column]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            for i, (u, v) in enumerate(zip(x, y)):
                both_nan = math.isnan(u) and math.isnan(v)
                if not both_nan and not math.isclose(u, v, rel_tol=REL_TOLERANCE, abs_tol=1e-12):
                    return f"column {column}, row {i}: {u!r} against {v!r}"
        elif not x.astype(str).equals(y.astype(str)):
            row = int((x.astype(str) != y.astype(str)).to_numpy().argmax())
            return f"column {column}, row {row}: {x.iloc[row]!r} against {y.iloc[row]!r}"
    return None


def compare_command(args) -> int:
    a, b = table_files(Path(args.a)), table_files(Path(args.b))
    if not a:
        print(f"no tables below {args.a}", file=sys.stderr)
        return 1
    if set(a) != set(b):
        print(f"different tables: only in {args.a}: {sorted(set(a) - set(b))}; "
              f"only in {args.b}: {sorted(set(b) - set(a))}", file=sys.stderr)
        return 1
    failed = 0
    for name in sorted(a):
        if a[name].read_bytes() == b[name].read_bytes():
            verdict = "identical"
        elif (difference := compare_table(a[name], b[name])) is None:
            measured = MEASURED_COLUMNS.get(a[name].name)
            verdict = (f"equal but for measured columns ({measured[1]})" if measured
                       else f"equal to a relative {REL_TOLERANCE:g}")
        else:
            verdict, failed = f"DIFFERENT: {difference}", failed + 1
        print(f"  {name}: {verdict}")
    return 1 if failed else 0


# --- Snakemake's own CPU time -----------------------------------------------------------------------------

def shares(local: dict, slurm: dict, slurm_jobs_cpu_s: float) -> dict:
    """Snakemake's own CPU time as a share of the run's. Local: the own process against the whole process
    tree (jobs and solver included). SLURM: the own process and the commands it runs (sbatch, sacct,
    any solver) against those plus the jobs' CPU time from sacct."""
    slurm_own = slurm["own_cpu_s"] + slurm["children_cpu_s"]
    return {
        "local_own_s": local["own_cpu_s"], "local_total_s": local["total_cpu_s"],
        "local_share": local["own_cpu_s"] / local["total_cpu_s"],
        "slurm_own_s": slurm["own_cpu_s"], "slurm_commands_s": slurm["children_cpu_s"],
        "slurm_jobs_s": slurm_jobs_cpu_s,
        "slurm_share": slurm_own / (slurm_own + slurm_jobs_cpu_s),
    }


def share_command(args) -> int:
    local, slurm = (json.loads(Path(p).read_text()) for p in (args.local, args.slurm))
    jobs_cpu = sum(job["cpu_s"] for job in json.loads(Path(args.slurm_jobs).read_text()))
    s = shares(local, slurm, jobs_cpu)
    print(f"  local: Snakemake's process {s['local_own_s']:.1f} s of {s['local_total_s']:.1f} s CPU "
          f"({100 * s['local_share']:.2f} %), wall {local['wall_s']:.0f} s")
    print(f"  SLURM: Snakemake's process {s['slurm_own_s']:.1f} s and the commands it ran (sbatch, sacct) "
          f"{s['slurm_commands_s']:.1f} s, against the jobs' {s['slurm_jobs_s']:.1f} s CPU "
          f"({100 * s['slurm_share']:.2f} %), wall {slurm['wall_s']:.0f} s")
    return 0


# --- the bad configuration --------------------------------------------------------------------------------

def bad_config_command(args) -> int:
    config = yaml.safe_load(Path(args.input).read_text())
    config.setdefault("simulator", {})["max_particles"] = 100
    Path(args.output).write_text(yaml.safe_dump(config, sort_keys=False))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    jobs = commands.add_parser("jobs")
    jobs.add_argument("--name", required=True)
    jobs.add_argument("--state")
    jobs.add_argument("--rule")
    jobs.add_argument("--json")
    compare = commands.add_parser("compare")
    compare.add_argument("a")
    compare.add_argument("b")
    share = commands.add_parser("share")
    for option in ("--local", "--slurm", "--slurm-jobs"):
        share.add_argument(option, required=True)
    bad = commands.add_parser("bad-config")
    bad.add_argument("input")
    bad.add_argument("output")
    args = parser.parse_args(argv)
    return {"jobs": jobs_command, "compare": compare_command, "share": share_command,
            "bad-config": bad_config_command}[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
