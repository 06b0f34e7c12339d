#!/usr/bin/env python3
"""How much CPU a command's own process uses beside the processes it starts (docs/benchmarks.md).

    .venv/bin/python scripts/cpu_share.py [--json FILE] -- snakemake -j1 tables

Runs the command and prints its wall time, the CPU time (user + system, seconds) of the command's own
process, of the processes it started and waited for (from the kernel's accounting of reaped children,
so exact), of those among them named like ``--solver`` (default ``cbc``, the ILP scheduler's solver;
sampled every 0.2 s, so a lower bound), and the own process's share of the whole. The own process's
figure is its last sample before it exited: at most one sampling interval short.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import psutil

INTERVAL_S = 0.2
"""Seconds between samples of the process tree."""


def measure(command: list[str], solver: str = "cbc", stdout=None) -> dict:
    """Run ``command`` to its end (its standard output to the file ``stdout``, if given); CPU seconds of
    its own process, of its reaped children and of the children named like ``solver``, its wall seconds
    and exit code."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.monotonic()
    process = subprocess.Popen(command, stdout=stdout)
    main = psutil.Process(process.pid)
    own = 0.0
    solver_seen: dict[int, float] = {}
    while process.poll() is None:
        try:
            times = main.cpu_times()
            own = times.user + times.system
            for child in main.children(recursive=True):
                if solver in child.name():
                    t = child.cpu_times()
                    solver_seen[child.pid] = max(solver_seen.get(child.pid, 0.0), t.user + t.system)
        except psutil.Error:  # a process ended between listing and reading it
            pass
        time.sleep(INTERVAL_S)
    wall = time.monotonic() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    tree = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "command": command,
        "returncode": process.returncode,
        "wall_s": wall,
        "own_cpu_s": own,
        "children_cpu_s": max(tree - own, 0.0),
        "solver_cpu_s": sum(solver_seen.values()),
        "solver_runs": len(solver_seen),
        "total_cpu_s": tree,
    }


def report(figures: dict) -> str:
    """The figures as lines of text, with the own process's share of the total CPU time."""
    share = figures["own_cpu_s"] / figures["total_cpu_s"] if figures["total_cpu_s"] else float("nan")
    return "\n".join([
        f"wall                {figures['wall_s']:9.1f} s",
        f"own process CPU     {figures['own_cpu_s']:9.1f} s  ({100 * share:.2f} % of the total)",
        f"children CPU        {figures['children_cpu_s']:9.1f} s  "
        f"(solver {figures['solver_cpu_s']:.1f} s in {figures['solver_runs']} runs seen)",
        f"total CPU           {figures['total_cpu_s']:9.1f} s",
    ])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", help="also write the figures to this file")
    parser.add_argument("--solver", default="cbc", help="process name of the scheduler's solver (default cbc)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command to measure after --")
    figures = measure(command, args.solver)
    print(report(figures), file=sys.stderr)
    if args.json:
        with open(args.json, "w") as out:
            json.dump(figures, out, indent=1)
    return figures["returncode"]


if __name__ == "__main__":
    sys.exit(main())
