#!/usr/bin/env python3
"""The paper's sweep on a cluster, on paper: jobs, CPU-hours and wall time on N nodes (docs/benchmarks.md).

    .venv/bin/python scripts/paper_scale.py passes --dx 0.005 --density 4e7 > passes.csv
    snakemake -n --configfile config/paper.yaml all identifiability > dry-run.txt
    .venv/bin/python scripts/paper_scale.py estimate dry-run.txt passes.csv slurm-jobs.json [--cores 16]

`passes` measures the CPU seconds of one forward and one backward pass of each motion of the cost table
(`python -m dpsi.bench _one`: the benchmark lump at the paper's density and grid cell, one thread): the CPU
time of a process doing three iterations less that of one doing one (after a first that fills Taichi's
kernel cache), halved, split into forward and
backward as the process's own timings split them. CPU time, unlike the cost table's wall time, does not
grow when other programs share the machine. `estimate` reads every job of the dry run (its rule and the
prepared datapoints among its inputs), those passes (or a cost table: forward_s and backward_s per
motion) and the per-job figures of a SLURM run of the tiny configuration (slurm-jobs.json from
scripts/slurm_check.py jobs: CPU seconds per job, the fixed cost of starting a job of each rule). Each
job's CPU time is modelled as:

- identification runs: iterations × (forward + backward of each training datapoint + forward of each
  validation datapoint; a run without validation datapoints validates on its training ones);
- loss landscapes: resolution² forwards of each datapoint; the ladder's landscapes 36;
- greedy planning: actions × grid² × motions forwards of poking-shifting;
- other simulating jobs: one forward of each datapoint; timing jobs: the first and the measured passes;
- the synthetic twin's datapoints and the rules that do not simulate: the tiny run's CPU time times a
  stated factor (see SCALE);
- every job also its rule's CPU time in the tiny run (starting Python, Taichi, the kernels).

Motions the cost table lacks take the time of the measured motion of their kind, times the ratio of their
steps. The wall time on N nodes of C cores is that of one CPU per job, jobs placed longest first in four
stages that each wait for the one before (twin and reconstruction; runs and analyses; what needs the
level-2 runs; tables and figures).
"""

from __future__ import annotations

import argparse
import heapq
import importlib.util
import json
import re
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import pandas as pd

from dpsi.motions import trajectory

ITERATIONS = 100
"""Iterations of every identification run in config/paper.yaml (main sweep, analyses, ladder)."""
LANDSCAPE_RESOLUTION = 30
LADDER_LANDSCAPE_SIMULATIONS = 36
PLANNING_FORWARDS = 8 * 3**2 * 2
"""greedy_plan in config/paper.yaml: 8 actions × a 3 × 3 grid × 2 motions."""
COST_PASSES = 1 + 3
"""cost_measure: the first forward + backward, then measured_iterations (3) more."""
COST_DENSITY_FACTOR = 1.5
"""cost_measure's densities (4, 6 and 8e7 per m³) against the cost table's lowest, on average."""
SCALE = {"twin_datapoint": 19.0, "other": 4.0}
"""The tiny run's CPU time times this: the twin's datapoints have 12.5 × the particles (1.5e8 against
1.2e7 per m³) and 1.5 × the substeps (4 mm cells against 6 mm); the other rules handle 4 × the particles
(reconstruction at 4e7 against 1e7 per m³)."""
UNMEASURED_S = 60.0
"""CPU seconds assumed in the tiny run for a rule it did not have (its jobs took 10-20 s, 57 s the longest)."""
MEASURED_KIN = {"poking-1": "poking-1", "poking-2": "poking-1", "poking-shifting-1": "poking-shifting-1",
                "poking-shifting-2": "poking-shifting-1", "flattening": "flattening",
                "triple-poking": "flattening", "poking-180-rotating": "flattening"}
"""Each motion's measured motion of the same kind in the cost table."""
IDENTIFICATION = {"identify", "identify_analysis", "identify_ladder"}
ONE_FORWARD = {"validate_hand_picked", "ood_identified", "ood_hand_picked", "ladder_same_model",
               "ladder_reference"}
STAGES = [
    {"twin_table", "twin_datapoint", "check_raw", "fuse", "mesh", "fill", "targets", "trajectory", "prepare"},
    None,  # everything not named in another stage
    {"ood_identified", "greedy_plan", "ladder_same_target", "identifiability_bias"},
    {"make_tables", "make_figures", "cost_table", "convergence_table", "landscape_figure", "materials_results",
     "minima_results", "heightmap_losses_results", "planning_report", "identifiability_results",
     "identifiability_landscapes"},
]


def dry_run_jobs(text: str) -> list[dict]:
    """Each job of a `snakemake -n` output that makes files and is not a local rule: its rule and its
    prepared datapoints (ids)."""
    jobs, job = [], None
    for line in text.splitlines():
        start = re.match(r"(local)?rule (\w+):", line)
        if start:
            job = None if start[1] else {"rule": start[2], "datapoints": [], "output": False}
            if job:
                jobs.append(job)
        elif job and line.strip().startswith("input:"):
            job["datapoints"] = list(dict.fromkeys(re.findall(r"prepared/([\w.+-]+)\.npz", line)))  # once each
        elif job and line.strip().startswith("output:"):
            job["output"] = True
    return [j for j in jobs if j["output"]]


def motion_of(datapoint: str) -> str:
    """The motion in a datapoint id such as clay-poking-shifting-2-round-train-0 (the longest known)."""
    found = [m for m in MEASURED_KIN if f"-{m}-" in f"-{datapoint}-"]
    if not found:
        raise ValueError(f"no known motion in datapoint id {datapoint!r}")
    return max(found, key=len)


def pass_seconds(cost: pd.DataFrame) -> dict[str, tuple[float, float]]:
    """Per motion: (forward, backward) seconds at the cost table's lowest density."""
    rows = cost[cost.density == cost.density.min()].set_index("motion")
    times = {}
    for motion, kin in MEASURED_KIN.items():
        ratio = trajectory(motion).n_steps / trajectory(kin).n_steps
        times[motion] = (rows.forward_s[kin] * ratio, rows.backward_s[kin] * ratio)
    return times


def job_cpu_seconds(job: dict, passes: dict, tiny: dict[str, float], cost: pd.DataFrame) -> float:
    """The modelled CPU seconds of one job (see the module's doc); ``tiny``: CPU seconds per job of each
    rule in the tiny run."""
    rule, datapoints = job["rule"], job["datapoints"]
    forward = lambda ids: sum(passes[motion_of(i)][0] for i in ids)  # noqa: E731
    both = lambda ids: sum(sum(passes[motion_of(i)]) for i in ids)  # noqa: E731
    base = tiny.get(rule, 0.0)
    if rule in IDENTIFICATION:
        validation = [i for i in datapoints if "-validation-" in i]
        training = [i for i in datapoints if i not in validation]
        return base + ITERATIONS * (both(training) + forward(validation or training))
    if rule == "landscape":
        return base + LANDSCAPE_RESOLUTION**2 * forward(datapoints)
    if rule == "ladder_landscape":
        return base + LADDER_LANDSCAPE_SIMULATIONS * forward(datapoints)
    if rule == "greedy_plan":
        return base + PLANNING_FORWARDS * passes["poking-shifting-1"][0]
    if rule == "cost_measure":
        lowest = cost[cost.density == cost.density.min()]
        return base + COST_PASSES * COST_DENSITY_FACTOR * (lowest.forward_s + lowest.backward_s).mean()
    if rule in ONE_FORWARD:
        return base + forward(datapoints)
    return tiny.get(rule, UNMEASURED_S) * SCALE.get(rule, SCALE["other"])


def makespan(durations: list[float], slots: int) -> float:
    """Wall seconds of independent one-CPU jobs on ``slots`` CPUs, the longest placed first."""
    ends = [0.0] * min(slots, max(len(durations), 1))
    for duration in sorted(durations, reverse=True):
        heapq.heappush(ends, heapq.heappop(ends) + duration)
    return max(ends)


def stage_of(rule: str) -> int:
    return next((i for i, rules in enumerate(STAGES) if rules and rule in rules), 1)


def measured_passes(motion: str, density: float, dx: float) -> dict:
    """CPU seconds of one forward and one backward pass of ``motion`` on the benchmark lump (see the doc)."""
    spec = importlib.util.spec_from_file_location("cpu_share", Path(__file__).with_name("cpu_share.py"))
    cpu_share = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cpu_share)
    cpu, timings = {}, {}
    for iterations in (1, 1, 3):  # the first warms Taichi's kernel cache: compiling would count as a pass
        command = [sys.executable, "-m", "dpsi.bench", "_one", motion, str(density), "--iterations",
                   str(iterations), "--simulator", json.dumps({"dx": dx, "threads": 1})]
        with tempfile.TemporaryFile("w+") as out:
            figures = cpu_share.measure(command, stdout=out)
            out.seek(0)
            if figures["returncode"] != 0:
                raise RuntimeError(f"the benchmark of {motion} failed: {' '.join(command)}")
            cpu[iterations], timings[iterations] = figures["total_cpu_s"], json.loads(out.read().splitlines()[-1])
    per_iteration = (cpu[3] - cpu[1]) / 2
    share = timings[3]["forward_s"] / (timings[3]["forward_s"] + timings[3]["backward_s"])
    return {"motion": motion, "density": density, "dx": dx, "particles": timings[3]["particles"],
            "substeps": timings[3]["substeps"], "forward_s": per_iteration * share,
            "backward_s": per_iteration * (1 - share)}


def estimate(args) -> int:
    jobs = dry_run_jobs(Path(args.dry_run).read_text())
    cost = pd.read_csv(args.cost)
    tiny_jobs = pd.DataFrame(json.loads(Path(args.slurm_jobs).read_text()))
    tiny = tiny_jobs.groupby("rule").cpu_s.mean().to_dict()
    passes = pass_seconds(cost)
    for job in jobs:
        job["cpu_s"] = job_cpu_seconds(job, passes, tiny, cost)
    table = pd.DataFrame(jobs)
    per_rule = table.groupby("rule").cpu_s.agg(["size", "mean", "max", "sum"])
    per_rule = per_rule.assign(cpu_h=per_rule["sum"] / 3600).sort_values("sum", ascending=False)
    print("per rule: jobs, CPU seconds per job (mean, longest), CPU-hours")
    for rule, row in per_rule.iterrows():
        print(f"  {rule:28s} {int(row['size']):5d} {row['mean']:9.0f} {row['max']:9.0f} {row.cpu_h:8.1f}")
    total_h = table.cpu_s.sum() / 3600
    print(f"{len(table)} jobs, {total_h:.0f} CPU-hours; the longest job {table.cpu_s.max() / 3600:.1f} h "
          f"({table.loc[table.cpu_s.idxmax(), 'rule']})")
    stages = defaultdict(list)
    for job in jobs:
        stages[stage_of(job["rule"])].append(job["cpu_s"])
    for nodes in args.nodes:
        slots = nodes * args.cores
        wall = sum(makespan(durations, slots) for durations in stages.values())
        print(f"{nodes:3d} node(s) of {args.cores} cores: wall {wall / 3600:6.1f} h "
              f"(the CPUs busy {100 * table.cpu_s.sum() / (wall * slots):.0f} % of it)")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    passes = commands.add_parser("passes")
    passes.add_argument("--dx", type=float, default=0.005)
    passes.add_argument("--density", type=float, default=4e7)
    passes.add_argument("--motions", nargs="+", default=["poking-1", "poking-shifting-1", "flattening"])
    est = commands.add_parser("estimate")
    est.add_argument("dry_run")
    est.add_argument("cost")
    est.add_argument("slurm_jobs")
    est.add_argument("--cores", type=int, default=16)
    est.add_argument("--nodes", type=int, nargs="+", default=[1, 4, 16])
    args = parser.parse_args(argv)
    if args.command == "estimate":
        return estimate(args)
    rows = [measured_passes(motion, args.density, args.dx) for motion in args.motions]
    print(pd.DataFrame(rows).to_csv(index=False), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
