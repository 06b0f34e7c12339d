"""Identification on the published real clay pairs (``../shared/real-clay``, see its README.md).

Each (before, after) mesh pair becomes a prepared :class:`~dpsi.datapoint.Datapoint`: the before mesh
filled with particles, the after mesh's targets from points sampled on it, and the effector trajectory
planned for the pair's motion with the tip starting at the top centre of the before mesh (the real
trajectories are not published). Identification runs at level 1 on one pair from the hand-picked values;
every other pair is then simulated with the identified and the hand-picked parameters and compared with
its real after state by the height-map distance (mm), next to the unmoved before shape.

Pairs and assumptions:

- ``cylinder-5`` (``data-motion-poking-1/eef-cylinder``, i = 5) and ``round-2`` (``…/eef-round``, i = 2)
  are poking-1.
- ``rectangle-8`` (``data-motion-1/eef-rectangle``, i = 8): the folder names no SPEC motion. We take
  poking-1 (−z 15 mm, +z 30 mm): "motion 1" is the paper's first level-1 motion, the after shape is the
  before shape pressed flat on top (no shifting, no rotation), and the measured top drop of 11 mm
  (35.1 → 24.1 mm) is closest to poking-1's 15 mm push (poking-2 pushes 20 mm, the long motions 25 mm).
- ``round-2`` is published normalised (each mesh centred on its own bounding box), so before and after
  share no frame. We align them: each mesh is shifted so that its lowest z lies on the table z = 0 and
  the after mesh's footprint centre (bounding-box centre in x, y) lies on the before mesh's.

With ``--grid`` the command identifies nothing: it simulates every pair over a grid of (E, σ_y) around the
hand-picked values and lists the cells closer to the real after states than the hand-picked values on every
pair (:func:`grid_landscapes`, :func:`grid_report`).

Lengths in m (robot base frame, table at z = 0); distances in mm.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import open3d as o3d

from dpsi.datapoint import Datapoint
from dpsi.heightmap import heightmap_distance_mm
from dpsi.effectors import by_name
from dpsi.identifiability_landscape import PAIR
from dpsi.identification import identify, scene
from dpsi.landscape_compute import on_grid
from dpsi.landscapes import Landscape, fixed_cell
from dpsi.losses import LOSSES, simulated_heightmap
from dpsi.motions import get_motion, plan, resample
from dpsi.parameters import HAND_PICKED, LEVEL1_FIXED, Parameters
from dpsi.files import atomic_output
from dpsi.pointclouds import read_mesh
from dpsi.prepare import after_targets, assemble, fill_particles, surface_points
from dpsi.simulation import SimulationError, Simulator, SimulatorConfig

TABLE_Z = 0.0
"""Height (m) of the table plane in the robot base frame of the real meshes."""

DEFAULT_SHARED = Path("../shared/real-clay")
"""Where the real pairs are, relative to the project root (the working directory of the command)."""


@dataclass(frozen=True)
class RealPair:
    """One published pair: before/after mesh paths relative to the real-clay folder, the effector, the
    SPEC motion assumed, and whether both meshes are in the robot base frame (else: normalised)."""

    before: str
    after: str
    effector: str
    motion: str
    common_frame: bool = True


PAIRS: dict[str, RealPair] = {
    "cylinder-5": RealPair("data-motion-poking-1/eef-cylinder/mesh_50.obj",
                           "data-motion-poking-1/eef-cylinder/mesh_51.obj", "cylinder", "poking-1"),
    "rectangle-8": RealPair("data-motion-1/eef-rectangle/mesh_80.obj", "data-motion-1/eef-rectangle/mesh_81.obj",
                            "rectangle", "poking-1"),
    "round-2": RealPair("data-motion-poking-1/eef-round/mesh_20.obj", "data-motion-poking-1/eef-round/mesh_21.obj",
                        "round", "poking-1", common_frame=False),
}
"""The usable real pairs by name (see the module doc for the motions and the alignment of ``round-2``)."""


def _translated(mesh: o3d.geometry.TriangleMesh, shift) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh(mesh).translate(np.asarray(shift, dtype=float))


def table_aligned(before: o3d.geometry.TriangleMesh,
                  after: o3d.geometry.TriangleMesh) -> tuple[o3d.geometry.TriangleMesh, o3d.geometry.TriangleMesh]:
    """A normalised pair put into one frame: each mesh's lowest z on the table z = 0, and the after
    mesh's bounding-box centre in (x, y) on the before mesh's."""
    lo_b, hi_b = before.get_min_bound(), before.get_max_bound()
    lo_a, hi_a = after.get_min_bound(), after.get_max_bound()
    centre_shift = (lo_b[:2] + hi_b[:2]) / 2 - (lo_a[:2] + hi_a[:2]) / 2
    return (_translated(before, [0.0, 0.0, TABLE_Z - lo_b[2]]),
            _translated(after, [*centre_shift, TABLE_Z - lo_a[2]]))


def check_shared(shared: str | Path) -> Path:
    """``shared`` as a Path, or ``FileNotFoundError`` saying where the real pairs are expected."""
    shared = Path(shared)
    if not (shared / "MANIFEST.csv").is_file():
        raise FileNotFoundError(f"real clay meshes not found at {shared} (no MANIFEST.csv); give the folder "
                                "with --shared (default ../shared/real-clay from the project root)")
    return shared


def pair_meshes(shared: str | Path, name: str) -> tuple[o3d.geometry.TriangleMesh, o3d.geometry.TriangleMesh]:
    """The (before, after) meshes of pair ``name`` in the robot base frame (aligned if published normalised)."""
    if name not in PAIRS:
        raise ValueError(f"unknown real pair {name!r}; known pairs are {sorted(PAIRS)}")
    shared, pair = check_shared(shared), PAIRS[name]
    before, after = read_mesh(shared / pair.before), read_mesh(shared / pair.after)
    return (before, after) if pair.common_frame else table_aligned(before, after)


def real_datapoint(shared: str | Path, name: str, density: float, seed: int = 0,
                   config: SimulatorConfig | None = None) -> Datapoint:
    """Prepared datapoint of pair ``name``: the before mesh filled at ``density`` particles/m³ (checked
    against the simulator ``config`` if given), targets of the after mesh (surface points sampled on it),
    and the pair's motion planned with ``seed`` from the top centre of the before mesh, resampled."""
    before, after = pair_meshes(shared, name)
    pair = PAIRS[name]
    particles = fill_particles(before, density, f"real pair {name} before mesh", config)
    targets = after_targets(after, surface_points(after), particles, density, TABLE_Z, measured=False)
    lo, hi = before.get_min_bound(), before.get_max_bound()
    waypoints = plan(get_motion(pair.motion), seed, start_xyz=[*(lo[:2] + hi[:2]) / 2, hi[2]])
    return assemble(name, pair.motion, by_name(pair.effector), particles, density, resample(waypoints),
                    waypoints.xyz[0], targets)


def heightmap_mm(dp: Datapoint, particles: np.ndarray) -> float:
    """Height-map distance (mm) of ``particles`` (n, 3), drawn as the datapoint's particle cubes, to the
    real after state of ``dp``."""
    return heightmap_distance_mm(simulated_heightmap(particles, dp.heightmap_target()), dp.heightmap)


def simulated_mm(simulator: Simulator, dp: Datapoint, params: Parameters) -> float:
    """Height-map distance (mm) to the real after state of ``dp`` simulated with ``params``; NaN if the
    simulation fails."""
    try:
        return heightmap_mm(dp, simulator.forward(scene(dp), params, keep_substeps=False))
    except SimulationError:
        return math.nan


def comparison_rows(simulator: Simulator, datapoints: Sequence[Datapoint], identified: Parameters,
                    hand_picked: Parameters, training: str | None = None) -> list[dict]:
    """Per datapoint: its role (``training`` if its id is ``training``, else unseen), the height-map
    distances (mm) to its real after state of the ``identified`` and ``hand_picked`` simulations and of
    the unmoved before particles, and the relative change identified vs hand-picked (negative: identified
    is closer)."""
    rows = []
    for dp in datapoints:
        ident, hand = simulated_mm(simulator, dp, identified), simulated_mm(simulator, dp, hand_picked)
        rows.append({"pair": dp.id, "role": "training" if dp.id == training else "unseen", "effector": dp.effector.name,
                     "motion": dp.motion, "particles": len(dp.particles), "identified_mm": ident,
                     "hand_picked_mm": hand, "unmoved_mm": heightmap_mm(dp, dp.particles),
                     "change": (ident - hand) / hand})
    return rows


def markdown_table(rows: Sequence[dict]) -> str:
    """The comparison rows as a markdown table (distances in mm, change in %)."""
    header = ("| pair | role | effector | motion | particles | identified (mm) | hand-picked (mm) | unmoved (mm) | "
              "identified vs hand-picked |")
    lines = [header, "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['pair']} | {r['role']} | {r['effector']} | {r['motion']} | {r['particles']} | "
                     f"{r['identified_mm']:.0f} | {r['hand_picked_mm']:.0f} | {r['unmoved_mm']:.0f} | "
                     f"{100 * r['change']:+.1f} % |")
    return "\n".join(lines) + "\n"


def identify_on_real(shared: str | Path, train: str, out_dir: str | Path, iterations: int, density: float,
                     loss: str, simulator: Simulator, seed: int = 0, progress=None) -> tuple[dict, list[dict]]:
    """Level-1 identification on pair ``train`` from the hand-picked values (validation set: the training
    pair itself, so the other pairs stay unseen; the best iteration is the one with the lowest height-map
    distance on it), then :func:`comparison_rows` on the training pair and every other pair. Returns
    (summary, rows)."""
    if train not in PAIRS:
        raise ValueError(f"unknown training pair {train!r}; known pairs are {sorted(PAIRS)}")
    datapoints = {name: real_datapoint(shared, name, density, seed, simulator.config) for name in PAIRS}
    training = [datapoints[train]]
    summary = identify(out_dir, 1, loss, training, training, seed=seed, iterations=iterations,
                       initial=HAND_PICKED, simulator=simulator, progress=progress, restart_if_different=True)
    if summary["best"] is None:
        raise RuntimeError(f"identification on {train} produced no finite validation height map; see {out_dir}")
    identified = Parameters.checked(**summary["best"]["parameters"])
    ordered = [datapoints[train], *(dp for name, dp in datapoints.items() if name != train)]
    return summary, comparison_rows(simulator, ordered, identified, HAND_PICKED.replace(**LEVEL1_FIXED), train)


GRID = {"E": (1e4, 1.5e4, 3e4, 6e4, 1.2e5, 2.4e5), "yield_stress": (1e3, 1.5e3, 2e3, 3e3, 5e3, 8e3)}
"""The (E, σ_y) values (Pa) of :func:`grid_landscapes`: around the hand-picked 30 kPa and 1 kPa, within
their ranges (σ_y's starts at the hand-picked value)."""


def grid_landscapes(simulator: Simulator, datapoints: Sequence[Datapoint]) -> dict[str, Landscape]:
    """Per datapoint, the height-map distance (mm) to its real after state over :data:`GRID`, ν, ρ and the
    frictions as hand-picked at level 1."""
    hand_picked = HAND_PICKED.replace(**LEVEL1_FIXED)
    return {dp.id: on_grid(simulator, [dp], PAIR, hand_picked, GRID["E"], GRID["yield_stress"], ["heightmap"])
            for dp in datapoints}


def grid_report(landscapes: Mapping[str, Landscape]) -> str:
    """Markdown of :func:`grid_landscapes`: per pair the hand-picked distance, the grid's lowest and where
    it is; then the (E, σ_y) cells closer than the hand-picked values on every pair."""
    lines = ["| pair | hand-picked (mm) | grid minimum (mm) | at E, σ_y (kPa) | change |", "|---|---|---|---|---|"]
    better = True
    for name, landscape in landscapes.items():
        values = landscape.values[0]
        hand = values[fixed_cell(landscape)]
        i, j = np.unravel_index(np.nanargmin(values), values.shape)
        lines.append(f"| {name} | {hand:.0f} | {values[i, j]:.0f} | {landscape.first[i] / 1e3:g}, "
                     f"{landscape.second[j] / 1e3:g} | {100 * (values[i, j] - hand) / hand:+.1f} % |")
        better = better & (values < hand)
    first = next(iter(landscapes.values()))
    cells = [f"({first.first[i] / 1e3:g}, {first.second[j] / 1e3:g})" for i, j in zip(*np.nonzero(better))]
    return ("\n".join(lines) + "\n\nCells (E, σ_y in kPa) closer than the hand-picked values on every pair: "
            + (", ".join(cells) if cells else "none") + ".\n")


def report(summary: dict, rows: Sequence[dict], train: str, loss: str, density: float, iterations: int,
           command: str) -> str:
    """The markdown section of one run: settings, the ``command`` that made it, identified parameters and
    the comparison table."""
    best = summary["best"]
    params = ", ".join(f"{k}={v:.4g}" for k, v in best["parameters"].items())
    return (f"### Trained on {train}, loss {loss}, {iterations} iterations, {density:.3g} particles/m³\n\n"
            f"`{command}` ({summary['wall_s']:.0f} s of identification)\n\n"
            f"Best iteration {best['iteration']} (lowest height-map distance on {train}: "
            f"{best['validation']['heightmap_mm']:.0f} mm); identified {params}.\n\n" + markdown_table(rows))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dpsi.real_clay", description=__doc__.split("\n\n")[0])
    parser.add_argument("--shared", default=str(DEFAULT_SHARED), help="folder of the real pairs (README.md there)")
    parser.add_argument("--train", default="cylinder-5", choices=sorted(PAIRS), help="pair to identify on")
    parser.add_argument("--iterations", type=int, default=15)
    parser.add_argument("--density", type=float, default=3e7, help="particles per m³")
    parser.add_argument("--loss", default="prt_emd", choices=list(LOSSES))
    parser.add_argument("--seed", type=int, default=0, help="seed of the planned trajectories")
    parser.add_argument("--work", default="results/real-clay", help="folder for the identification runs")
    parser.add_argument("--out", help="markdown file to write the section to (printed in any case)")
    parser.add_argument("--grid", action="store_true",
                        help="instead of identifying: every pair's height-map distance over a grid of (E, σ_y)")
    args = parser.parse_args(argv)
    try:
        check_shared(args.shared)
    except FileNotFoundError as err:
        print(err, file=sys.stderr)
        return 2
    simulator = Simulator(SimulatorConfig())
    if args.grid:
        datapoints = [real_datapoint(args.shared, name, args.density, args.seed, simulator.config) for name in PAIRS]
        return _write(grid_report(grid_landscapes(simulator, datapoints)), args.out)
    run_dir = Path(args.work) / f"{args.train}-{args.loss}-{args.density:.3g}-{args.iterations}"
    summary, rows = identify_on_real(args.shared, args.train, run_dir, args.iterations, args.density, args.loss,
                                     simulator, args.seed)
    command = " ".join(["python -m dpsi.real_clay", *(argv if argv is not None else sys.argv[1:])])
    text = report(summary, rows, args.train, args.loss, args.density, args.iterations, command)
    with atomic_output(run_dir / "comparison.json") as tmp:
        tmp.write_text(json.dumps(rows, indent=2) + "\n")
    return _write(text, args.out)


def _write(text: str, out: str | None) -> int:
    """Print ``text`` and write it to ``out`` too if given; the command's exit status."""
    if out:
        with atomic_output(out) as tmp:
            tmp.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
