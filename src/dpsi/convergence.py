"""Resolution study: how the simulated result of a motion changes with the grid cell dx.

One lump (:func:`dpsi.shapes.random_lump` at :data:`dpsi.twin.CENTRE`) is filled at a density that keeps
:data:`PARTICLES_PER_CELL` particles per cell along each axis (spacing ≤ dx / 2) and pushed by the round
effector along a planner trajectory starting at the lump's top centre, as the twin does
(:func:`dpsi.twin.generate_datapoint`), with the clay truth parameters. The lump and the trajectory do not
depend on dx, so every difference between two rows of one motion comes from the resolution.

Each dx runs in a child process of its own (a simulator's fields are sized by dx and particle count and
are never freed within a process, and the peak memory is then the run's own). Per (motion, dx) the table
gives the top surface's height-map distance (mm, :func:`dpsi.heightmap.heightmap_distance_mm`) to the
finest dx, that of the initial particles (what the fill alone contributes: the lattice's top layer lies
up to one spacing below the lump's surface), the final height map's distance to the next finer dx's, the
dent depth (mm) under the effector, and the
cost: particles, substeps per 0.01 s step, forward time (s, kernels already compiled) and peak memory
(MiB).

    python -m dpsi.convergence --dx 8 6 5 4 3 --out results/tables/convergence.csv
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from dpsi.arguments import at_least, positive, simulator_settings
from dpsi.bench import peak_rss_mb
from dpsi.effectors import by_name
from dpsi.heightmap import CELLS, SIZE, height_map, heightmap_distance_mm
from dpsi.motions import MOTIONS as KNOWN_MOTIONS, Trajectory, get_motion, plan, resample
from dpsi.output_folder import writable_folder
from dpsi.reconstruction.filling import fill, lattice_spacing
from dpsi.shapes import random_lump
from dpsi.twin import CENTRE, TABLE_Z
from dpsi.twin_plan import MATERIALS

MOTIONS = ("poking-2", "poking-shifting-2")
"""Motions of the study (level 1 and level 2 training motions of the twin)."""

DX_MM = (8.0, 6.0, 5.0, 4.0, 3.0)
"""Grid cells (mm) of the study by default; 2 mm needs ~10 GB for the simulator's fields at this lump."""

EFFECTOR = "round"
MATERIAL = "clay"

LUMP_SEED = 3
"""Seed of the lump: 4.1 × 4.2 × 3.5 cm, 3.8e-5 m³, so a 20 mm poke ends 15 mm above the table."""

PARTICLES_PER_CELL = 2
"""Particles per grid cell along each axis: density = (PARTICLES_PER_CELL / dx)³."""

DENT_RADIUS = 0.005
"""Height-map cells whose centres lie within this distance (m) of the poke point make the dent depth."""

TOLERANCE_MM = 300.0
"""Height-map distance (mm) to the finest run within which a dx counts as converged (issue 10)."""

COLUMNS = ["motion", "dx_mm", "density", "particles", "substeps", "heightmap_to_finest_mm",
           "initial_heightmap_to_finest_mm", "heightmap_to_next_finer_mm", "dent_depth_mm", "forward_s", "peak_mem_mib"]


def density_for(dx: float) -> float:
    """Particles/m³ keeping :data:`PARTICLES_PER_CELL` per axis in a cell of ``dx`` m."""
    if not dx > 0:
        raise ValueError(f"grid cell dx must be a positive length in m, not {dx}")
    return (PARTICLES_PER_CELL / dx) ** 3


@dataclass(frozen=True)
class Setup:
    """What every dx shares: the lump mesh, the footprint centre (m) the height maps are centred at, and
    per motion the effector's start (m, top centre) and trajectory."""

    lump: object
    centre_xy: np.ndarray
    start: np.ndarray
    trajectories: dict[str, Trajectory]

    @classmethod
    def make(cls, motions=MOTIONS, seed: int = LUMP_SEED) -> "Setup":
        lump = random_lump(seed, CENTRE, TABLE_Z)
        lo, hi = lump.get_min_bound(), lump.get_max_bound()
        centre_xy = (lo[:2] + hi[:2]) / 2
        start = np.array([*centre_xy, hi[2]])
        trajectories = {m: resample(plan(get_motion(m), seed, start_xyz=start)) for m in motions}
        return cls(lump, centre_xy, start, trajectories)


def poke_point(trajectory: Trajectory, start: np.ndarray) -> np.ndarray:
    """Where the poke's dent is (x, y in m): the tip when it first reaches its lowest height (for
    poking-shifting the poke before the shift, whose trench the shift leaves behind)."""
    z = trajectory.positions[:, 2]
    first = np.flatnonzero(z <= z.min() + 1e-9)[0]
    return start[:2] + trajectory.positions[first, :2]


def dent_depth_mm(initial_map: np.ndarray, final_map: np.ndarray, centre_xy, point_xy,
                  radius: float = DENT_RADIUS) -> float:
    """Mean drop (mm) of the top surface from ``initial_map`` to ``final_map`` (height maps in m centred at
    ``centre_xy``) over the cells whose centres lie within ``radius`` m of ``point_xy``."""
    cell = SIZE / CELLS
    axis = np.asarray(centre_xy, float)[:, None] - SIZE / 2 + (np.arange(CELLS) + 0.5) * cell
    near = np.hypot(*np.meshgrid(axis[0] - point_xy[0], axis[1] - point_xy[1], indexing="ij")) <= radius
    if not near.any():
        raise ValueError(f"no height-map cell lies within {radius} m of the poke point {point_xy}")
    return float((initial_map - final_map)[near].mean() * 1000.0)


def simulate_dx(dx: float, motions=MOTIONS, seed: int = LUMP_SEED, simulator: dict | None = None) -> dict:
    """Simulate each motion at grid cell ``dx`` (m) on the study's lump with the clay truth.

    ``simulator``: further :class:`~dpsi.simulation.SimulatorConfig` settings (arch, cfl, …; not dx or
    max_particles). Returns the initial particles (n, 3), per motion the final particles, and the cost.
    The forward pass is timed after a one-step run has compiled the kernels."""
    from dpsi.simulation import Scene, Simulator, SimulatorConfig

    setup = Setup.make(motions, seed)
    density = density_for(dx)
    particles = fill(setup.lump, density)
    sim = Simulator(SimulatorConfig(dx=dx, max_particles=len(particles), **(simulator or {})))
    params = MATERIALS[MATERIAL]

    def scene(trajectory):
        return Scene(particles, 1.0 / density, by_name(EFFECTOR), trajectory, setup.start, TABLE_Z)

    first = setup.trajectories[motions[0]]
    sim.forward(scene(Trajectory(first.positions[:2], first.yaw[:2], first.dt)), params, keep_substeps=False)
    finals, seconds = {}, {}
    for motion in motions:
        began = time.perf_counter()
        finals[motion] = sim.forward(scene(setup.trajectories[motion]), params, keep_substeps=False)
        seconds[motion] = time.perf_counter() - began
    return dict(dx=dx, density=density, particles=particles, finals=finals, forward_s=seconds,
                substeps=sim.config.substeps(params), peak_mem_mib=peak_rss_mb())


def simulate_dx_isolated(dx: float, motions=MOTIONS, seed: int = LUMP_SEED, simulator: dict | None = None) -> dict:
    """:func:`simulate_dx` in a child process of its own (see the module doc)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.npz"
        command = [sys.executable, "-m", "dpsi.convergence", "--child", str(path), "--dx", str(dx * 1000),
                   "--seed", str(seed), "--motions", *motions, "--simulator", json.dumps(simulator or {})]
        out = subprocess.run(command, capture_output=True, text=True)
        if out.returncode != 0:
            raise RuntimeError(f"resolution study at dx={dx * 1000:g} mm failed:\n{out.stderr[-3000:]}")
        return _load_run(path)


def _save_run(path: Path, run: dict) -> None:
    meta = {k: run[k] for k in ("dx", "density", "forward_s", "substeps", "peak_mem_mib")}
    np.savez(path, meta=json.dumps(meta), particles=run["particles"],
             **{f"final/{m}": final for m, final in run["finals"].items()})


def _load_run(path: Path) -> dict:
    with np.load(path) as data:
        run = json.loads(str(data["meta"]))
        run["particles"] = data["particles"]
        run["finals"] = {k.split("/", 1)[1]: data[k] for k in data.files if k.startswith("final/")}
    return run


def convergence_table(runs: list[dict], motions=MOTIONS, seed: int = LUMP_SEED) -> pd.DataFrame:
    """The study's table (:data:`COLUMNS`) from :func:`simulate_dx` results, finest dx last per motion."""
    if not runs:
        raise ValueError("resolution study: no runs to tabulate")
    setup = Setup.make(motions, seed)
    runs = sorted(runs, key=lambda r: -r["dx"])
    rows = []
    for motion in motions:
        maps = []
        for run in runs:
            size = lattice_spacing(run["density"])
            initial, final = (height_map(p, setup.centre_xy, floor=TABLE_Z, particle_size=size)
                              for p in (run["particles"], run["finals"][motion]))
            maps.append((initial, final))
        point = poke_point(setup.trajectories[motion], setup.start)
        for k, (run, (initial, final)) in enumerate(zip(runs, maps)):
            finer = maps[k + 1] if k + 1 < len(maps) else None
            rows.append(dict(
                motion=motion, dx_mm=round(run["dx"] * 1000, 6), density=run["density"],
                particles=len(run["particles"]), substeps=run["substeps"],
                heightmap_to_finest_mm=heightmap_distance_mm(final, maps[-1][1]),
                initial_heightmap_to_finest_mm=heightmap_distance_mm(initial, maps[-1][0]),
                heightmap_to_next_finer_mm=heightmap_distance_mm(final, finer[1]) if finer else np.nan,
                dent_depth_mm=dent_depth_mm(initial, final, setup.centre_xy, point),
                forward_s=run["forward_s"][motion], peak_mem_mib=run["peak_mem_mib"]))
    return pd.DataFrame(rows, columns=COLUMNS)


def resolution_study(dx_mm=DX_MM, motions=MOTIONS, seed: int = LUMP_SEED, simulator: dict | None = None,
                     log=None) -> pd.DataFrame:
    """Run every dx (mm) in its own process, coarsest first, and return :func:`convergence_table`."""
    motions = tuple(motions)
    for m in motions:
        get_motion(m)
    dx_mm = sorted({float(d) for d in dx_mm}, reverse=True)
    if len(dx_mm) < 2 or dx_mm[-1] <= 0:
        raise ValueError(f"resolution study needs at least two positive dx values in mm, got {dx_mm}")
    runs = []
    for dx in dx_mm:
        runs.append(simulate_dx_isolated(dx / 1000, motions, seed, simulator))
        if log:
            log(f"dx={dx:g} mm: {len(runs[-1]['particles'])} particles, {runs[-1]['substeps']} substeps, "
                f"forward {runs[-1]['forward_s']} s, peak {runs[-1]['peak_mem_mib']:.0f} MiB")
    return convergence_table(runs, motions, seed)


def recommended_dx_mm(table: pd.DataFrame, tolerance_mm: float = TOLERANCE_MM) -> float:
    """The coarsest dx (mm) whose final height map lies within ``tolerance_mm`` of the finest run's for
    every motion, and so does every finer dx's."""
    worst = table.groupby("dx_mm")["heightmap_to_finest_mm"].max().sort_index()
    within = worst <= tolerance_mm
    chosen = worst.index[0]  # the finest; walk up from it to the first dx that leaves the tolerance
    for dx in worst.index:
        if not within[dx]:
            break
        chosen = dx
    return float(chosen)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dpsi.convergence", description=__doc__.split("\n\n")[0])
    parser.add_argument("--motions", nargs="+", default=list(MOTIONS), choices=sorted(KNOWN_MOTIONS),
                        metavar="MOTION", help=f"motions (round effector; default {' '.join(MOTIONS)})")
    parser.add_argument("--dx", nargs="+", type=positive, default=list(DX_MM), help="grid cells in mm")
    parser.add_argument("--seed", type=at_least(0), default=LUMP_SEED, help="seed of the lump and trajectories")
    parser.add_argument("--simulator", type=simulator_settings(("dx", "max_particles")), default={},
                        help='further SimulatorConfig settings as JSON, e.g. {"arch": "cpu", "cfl": 0.7}')
    parser.add_argument("--out", default="results/tables/convergence.csv",
                        help="CSV to write (with .md and .tex beside it)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        if args.child:
            _save_run(Path(args.child), simulate_dx(args.dx[0] / 1000, tuple(args.motions), args.seed, args.simulator))
            return 0
        if len(set(args.dx)) < 2:
            parser.error(f"argument --dx: needs at least two different grid cells, got {args.dx}")
        if Path(args.out).is_dir():
            parser.error(f"argument --out: {args.out} is a folder; give the CSV file to write")
        writable_folder(Path(args.out).parent)
        from dpsi.reporting.tables import write_table

        table = resolution_study(args.dx, args.motions, args.seed, args.simulator,
                                 log=lambda s: print(s, flush=True))
        write_table(table, args.out, caption="Resolution study: clay truth, round effector, lump seed "
                    f"{args.seed}; height-map distances to the finest dx")
    except (ValueError, RuntimeError, OSError) as err:
        print(f"{parser.prog}: error: {err}", file=sys.stderr)
        return 1
    print(table.to_string(index=False))
    print(f"coarsest dx within {TOLERANCE_MM:g} mm of the finest: {recommended_dx_mm(table):g} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
