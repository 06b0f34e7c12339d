"""Command line: ``python -m dpsi`` (or ``dpsi``) with the subcommands ``simulate``, ``identify`` and
``import-release``.

Only parsing lives here; the work is done by :mod:`dpsi.prepare`, :mod:`dpsi.identification` and the
simulator. Shapes are point-cloud files (a fused, closed cloud: .ply .pcd .xyz .npy) or watertight
meshes (.obj, or a .ply with faces), in the robot base frame, in metres.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import logging
import os
import sys
from pathlib import Path

import yaml

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")  # stdout is for results; set before Taichi loads

from dpsi.arguments import at_least, finite, positive
from dpsi.datapoint import Datapoint
from dpsi.effectors import BUILT_IN, by_name
from dpsi.identification import IdentificationError, evaluate, identify
from dpsi.motion_offsets import register, shifted
from dpsi.losses import LOSSES
from dpsi.motions import MOTIONS, check_effector, get_motion, trajectory
from dpsi.output_folder import writable_folder
from dpsi.parameters import (HAND_PICKED, IDENTIFIED, LEVEL1_FIXED, NAMES, UNITS, Parameters, at_bound, hand_picked,
                             random_initial)
from dpsi.plausibility import check_plausible
from dpsi.pointclouds import CLOUD_SUFFIXES, MESH_SUFFIXES
from dpsi.prepare import after_targets, assemble, density_holding, fill_particles, reconstruct_state
from dpsi.rawdata import StateSource
from dpsi.release import import_release
from dpsi.release_plan import ImportTables
from dpsi.shape_files import ply_has_faces
from dpsi.simulation import SimulationError, Simulator, SimulatorConfig
from dpsi.uncertainty import describe

DENSITY = 4e7
"""Default particle density (particles/m³), the lowest of SPEC §3.3."""
MAX_PARTICLES = SimulatorConfig().max_particles


def _source(path: str) -> StateSource:
    """A shape file as a state source: a mesh if it has faces (.obj, or a .ply whose header declares faces),
    else a fused cloud; ``ValueError`` naming the accepted types for any other file type."""
    suffix = Path(path).suffix.lower()
    if suffix not in CLOUD_SUFFIXES + MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported shape file type {suffix!r}; use a point cloud "
                         f"({', '.join(CLOUD_SUFFIXES)}) or a watertight mesh (.obj, or .ply with faces)")
    mesh = suffix == ".obj" or (suffix == ".ply" and Path(path).is_file() and ply_has_faces(path))
    return StateSource("mesh" if mesh else "fused", (Path(path),))


def _shapes_datapoint(before: str, after: str, motion: str, effector: str, density: float,
                      table_z: float | None, config: SimulatorConfig) -> Datapoint:
    """A datapoint from a before and an after shape: the table is the plane z = ``table_z`` (m), by default
    through the before shape's lowest point; the tip starts at the top centre of the before shape's
    bounding box and follows the resampled ``motion``. Raises naming the file if the before shape does not
    fit the simulator of ``config`` (its box, or its particle capacity at ``density``), or holds fewer
    particles than the after shape's PCD target has points, if the motion is made with another effector
    (SPEC §2), or if the pair is not a possible capture (:func:`~dpsi.plausibility.check_plausible`, whose
    warnings are printed)."""
    check_effector(motion, effector, effector)
    shape = by_name(effector)
    _, before_mesh = reconstruct_state(_source(before), None, 0.0, before, config)
    after_points, after_mesh = reconstruct_state(_source(after), None, 0.0, after, config)
    lo, hi = before_mesh.get_min_bound(), before_mesh.get_max_bound()
    table_z = float(lo[2]) if table_z is None else table_z
    particles = fill_particles(before_mesh, density, before, config)
    targets = after_targets(after_mesh, after_points, particles, density, table_z, _source(after).measured)
    # checked before simulating: the validation metrics include its EMD
    if len(targets.pcd_target) > len(particles):
        raise ValueError(f"{before}: at --density {density:.3g} the object has {len(particles)} particles, fewer "
                         f"than the {len(targets.pcd_target)} points of the PCD target of {after} (the earth "
                         f"mover's distance needs no more target points than particles); use --density "
                         f"{density_holding(before_mesh, len(targets.pcd_target), density):.3g} or more")
    start = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]]
    dp = assemble(Path(before).stem, motion, shape, particles, density, trajectory(motion), start, targets)
    for warning in check_plausible(dp, before, after, f"the {motion} path from the top of {before}", "--table-z"):
        print(f"dpsi: warning: {warning}", file=sys.stderr)
    return dp


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    if name not in NAMES:
        raise argparse.ArgumentTypeError(f"unknown parameter {name!r}; known parameters are {list(NAMES)}")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"value of {name} must be a number, got {value!r}") from None


def _shape_options(parser: argparse.ArgumentParser, many: bool) -> None:
    each = (" (repeat once per datapoint; a single --motion/--effector applies to all; or give --datapoints)"
            if many else "")
    action = "append" if many else "store"
    parser.add_argument("--before", required=not many, action=action, metavar="FILE",
                        help="shape before the motion: point cloud or watertight mesh (small scan defects are "
                             "repaired and reported), base frame, m" + each)
    parser.add_argument("--after", required=not many, action=action, metavar="FILE",
                        help="shape after the motion, same forms as --before")
    parser.add_argument("--motion", required=not many, action=action, choices=sorted(MOTIONS),
                        help="robot motion; the tip starts at the top centre of the before shape")
    parser.add_argument("--effector", required=not many, action=action, choices=sorted(BUILT_IN),
                        help="end-effector shape")
    parser.add_argument("--estimate-offset", action="store_true",
                        help="first register where the robot really went (the motion's offset, up to a few mm) "
                             "from the dent in the after shape, at the hand-picked values, and simulate that "
                             "path (dpsi.motion_offsets)")
    parser.add_argument("--density", type=positive, default=DENSITY, metavar="D",
                        help=f"particle density in particles/m³ (default {DENSITY:g})")
    parser.add_argument("--table-z", type=finite, metavar="Z",
                        help="table height in m (default: the before shape's lowest point)")
    parser.add_argument("--max-particles", type=at_least(1), default=MAX_PARTICLES, metavar="N",
                        help=f"particle capacity of the simulator (default {MAX_PARTICLES}); more needs more memory")


def _param_help(what: str) -> str:
    listed = ", ".join(f"{n} ({UNITS[n]})" for n in NAMES)
    return f"{what}, repeatable; names: {listed}"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dpsi", description="Differentiable physics-based system identification "
                                     "of elastoplastic objects (SI units; metrics in mm).")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = commands.add_parser("simulate", help="simulate one motion and compare with the after shape",
                              description="Fill the before shape with particles, simulate the motion and print "
                                          "the five validation metrics (mm) against the after shape.")
    sim.set_defaults(parser=sim)
    _shape_options(sim, many=False)
    sim.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                     help=_param_help("a physical parameter (unset ones take the hand-picked values)"))
    sim.add_argument("--json", action="store_true", help="print one JSON object with keys particles, "
                     "heightmap_mm, pcd_cd, prt_cd, pcd_emd, prt_emd, params")

    ident = commands.add_parser("identify", help="identify the parameters from (before, after) pairs",
                                description="Gradient-based identification (SPEC §6). Writes log.csv, "
                                            "summary.json and state.json to --out (never over such files it did "
                                            "not write; one run per folder at a time); rerunning resumes.")
    ident.set_defaults(parser=ident)
    _shape_options(ident, many=True)
    ident.add_argument("--validate", nargs=4, action="append", default=[],
                       metavar=("BEFORE", "AFTER", "MOTION", "EFFECTOR"),
                       help="a validation datapoint, repeatable (default: validate on the training datapoints)")
    ident.add_argument("--loss", required=True, choices=list(LOSSES), help="training loss")
    ident.add_argument("--level", type=int, default=1, choices=sorted(IDENTIFIED),
                       help="1: identify E, nu, rho, yield_stress (frictions fixed); 2: all six (default 1)")
    ident.add_argument("--seed", type=at_least(0), default=0, help="seed of the random initial values (default 0)")
    ident.add_argument("--iterations", type=at_least(1), default=100, help="Adam updates (default 100)")
    ident.add_argument("--initial", choices=["random", "hand-picked"], default="random",
                       help="initial values: uniform random from --seed, or the hand-picked ones (default random)")
    ident.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help=_param_help("an initial value overriding --initial"))
    ident.add_argument("--known", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help=_param_help("a measured parameter held at this value instead of identified (e.g. "
                                        "rho from weighing the sample: E, rho and yield_stress times one factor "
                                        "give the same motion)"))
    ident.add_argument("--datapoints", metavar="CSV",
                       help="training datapoints as a CSV with columns before, after, motion, effector (one row "
                            "each; paths relative to the CSV's folder), instead of --before/--after/--motion/"
                            "--effector: one identification can span motions and effectors")
    ident.add_argument("--out", required=True, metavar="DIR", help="output folder")
    ident.add_argument("--uncertainty", action=argparse.BooleanOptionalAction, default=True,
                       help="measure at the best iteration what the data determine: an interval for each parameter, "
                            "E/rho, yield_stress/E and the stiffest direction (two gradient passes per identified "
                            "parameter; default on)")
    ident.add_argument("--json", action="store_true", help="print the run's summary (as saved in summary.json, "
                       "its intervals under 'uncertainty') as one JSON object")

    imp = commands.add_parser("import-release", help="the paper's published real pairs as a raw dataset",
                              description="Write the published real clay pairs under SOURCE (a clone of the data "
                                          "release, its data/ folder, or a folder with its MANIFEST.csv) as a raw "
                                          "dataset in OUT (docs/raw-format.md), repairing and reporting small mesh "
                                          "defects; prints one JSON line per datapoint.")
    imp.set_defaults(parser=imp)
    imp.add_argument("source", metavar="SOURCE", help="the release's root or data/ folder, or ../shared/real-clay")
    imp.add_argument("out", metavar="OUT", help="new folder for the raw dataset, e.g. raw/real-clay")
    imp.add_argument("--config", required=True, metavar="YAML",
                     help="a workflow config whose `release` section maps folders to motions, levels and effectors "
                          "(e.g. config/real.yaml)")
    return parser


def _params(parser, base: Parameters, pairs) -> Parameters:
    try:
        return base.replace(**dict(pairs))
    except ValueError as err:
        parser.error(f"argument --param: {err}")


def _one_each(parser, args, name: str) -> list[str]:
    values, n = getattr(args, name), len(args.before)
    if len(values) not in (1, n):
        parser.error(f"argument --{name}: give it once or once per --before ({n} times), not {len(values)} times")
    return values * n if len(values) == 1 else values


def _registered(simulator: Simulator, datapoints: list[Datapoint], level: int, offsets: dict) -> list[Datapoint]:
    """The datapoints with their motion offsets registered at the hand-picked values of ``level``, each
    offset (mm) noted in ``offsets`` by datapoint id."""
    moved = []
    for dp in datapoints:
        registration = register(simulator, dp, hand_picked(level))
        offsets[dp.id] = [round(v * 1e3, 3) for v in registration.offset]
        moved.append(shifted(dp, registration.offset))
    return moved


def _simulate(args, repairs: list[dict]) -> list[str]:
    config = SimulatorConfig(max_particles=args.max_particles)
    dp = _shapes_datapoint(args.before, args.after, args.motion, args.effector, args.density, args.table_z, config)
    simulator, offsets = Simulator(config), {}
    if args.estimate_offset:
        (dp,) = _registered(simulator, [dp], 1 if get_motion(args.motion).level == 1 else 2, offsets)
    metrics = evaluate(simulator, dp, args.params)
    result = {"particles": len(dp.particles), **metrics, "params": args.params.as_dict(), "repairs": repairs}
    if args.estimate_offset:
        result["motion_offset_mm"] = offsets[dp.id]
    if args.json:
        return [json.dumps(result)]
    return ([f"particles: {result['particles']}"] + [f"{name}: {value:.3f} mm" for name, value in metrics.items()]
            + [f"{name}: {value:g} {UNITS[name]}" for name, value in result["params"].items()]
            + [f"motion offset: {offsets[dp.id]} mm" for _ in offsets] + _repair_lines(repairs))


def _repair_lines(repairs: list[dict]) -> list[str]:
    return [f"repaired {r['file']}: {r['count']} {r['what']}" for r in repairs]


def _datapoint_rows(parser, args) -> list[tuple[str, str, str, str]]:
    """(before, after, motion, effector) of each training datapoint: from --datapoints, or the shape options."""
    if args.datapoints is None:
        if not args.before or not args.after or not args.motion or not args.effector:
            parser.error("give --before, --after, --motion and --effector (once per datapoint), or --datapoints")
        if len(args.after) != len(args.before):
            parser.error(f"argument --after: give one per --before ({len(args.before)}), got {len(args.after)}")
        return list(zip(args.before, args.after, _one_each(parser, args, "motion"), _one_each(parser, args, "effector")))
    if any((args.before, args.after, args.motion, args.effector)):
        parser.error("argument --datapoints: give either it or --before/--after/--motion/--effector, not both")
    return _datapoints_csv(parser, Path(args.datapoints))


DATAPOINT_COLUMNS = ("before", "after", "motion", "effector")
"""Columns of a --datapoints file."""


def _datapoints_csv(parser, path: Path) -> list[tuple[str, str, str, str]]:
    """The rows of a --datapoints CSV, shape paths resolved against its folder; the parser's error names the
    file, the line and what is wrong."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f, skipinitialspace=True))
            header = [name.strip() for name in (rows[0].keys() if rows else [])]
    except OSError as err:
        parser.error(f"argument --datapoints: cannot read {path} ({err.strerror})")
    missing = [c for c in DATAPOINT_COLUMNS if c not in header]
    if not rows or missing:
        parser.error(f"argument --datapoints: {path} needs a header with columns {list(DATAPOINT_COLUMNS)} and "
                     f"one row per datapoint" + (f"; missing {missing}" if rows else ""))
    out = []
    for line, row in enumerate(({k.strip(): (v or "").strip() for k, v in r.items()} for r in rows), start=2):
        if row["motion"] not in MOTIONS or row["effector"] not in BUILT_IN:
            parser.error(f"argument --datapoints: {path} line {line}: unknown motion {row['motion']!r} or effector "
                         f"{row['effector']!r}; motions are {sorted(MOTIONS)}, effectors {sorted(BUILT_IN)}")
        shape = lambda name: str(path.parent / row[name])  # noqa: E731
        out.append((shape("before"), shape("after"), row["motion"], row["effector"]))
    return out


def _identify(parser, args, repairs: list[dict]) -> list[str]:
    rows = _datapoint_rows(parser, args)
    fixed = sorted({name for name, _ in args.param} & set(LEVEL1_FIXED)) if args.level == 1 else []
    if fixed:
        parser.error(f"argument --param: level 1 keeps {', '.join(fixed)} fixed at {LEVEL1_FIXED}; "
                     "drop the option, or identify the frictions with --level 2")
    base = HAND_PICKED if args.initial == "hand-picked" else random_initial(args.seed, args.level)
    initial = _params(parser, base, args.param)
    writable_folder(args.out)  # before the shapes are prepared; identify claims it before simulating
    config = SimulatorConfig(max_particles=args.max_particles)
    training = [_shapes_datapoint(*row, args.density, args.table_z, config) for row in rows]
    validation_set = ([_shapes_datapoint(*quad, args.density, args.table_z, config) for quad in args.validate]
                      or training)
    simulator, offsets = Simulator(config), {}
    if args.estimate_offset:
        registered = dict(zip(map(id, training), _registered(simulator, training, args.level, offsets)))
        others = [dp for dp in validation_set if id(dp) not in registered]
        registered.update(zip(map(id, others), _registered(simulator, others, args.level, offsets)))
        training, validation_set = ([registered[id(dp)] for dp in dps] for dps in (training, validation_set))
    summary = identify(args.out, args.level, args.loss, training, validation_set, args.seed, args.iterations,
                       initial, simulator=simulator, known=dict(args.known), uncertainty=args.uncertainty)
    best = summary["best"]
    if best is None:
        raise IdentificationError(f"no updated iteration could be validated (every validation simulation failed "
                                  f"or gave no finite height-map distance: see val_skipped in "
                                  f"{Path(args.out) / 'log.csv'}); nothing identified")
    if args.json:
        return [json.dumps(summary)]
    held = [f"{name} was held at the given value (--known)" for name, _ in args.known]
    values = best["parameters"]
    bounds = at_bound(values, [n for n in IDENTIFIED[args.level] if n not in dict(args.known)])
    marked = (f"{name}: {value:g} {UNITS[name]}" + (f" (at its {bounds[name]} bound: the data may want a value outside "
                                                    "the range)" if name in bounds else "")
              for name, value in values.items())
    return [f"best iteration {best['iteration']} (validation height map {best['validation']['heightmap_mm']:.1f} mm):",
            *marked, *held,
            *(f"motion offset of {i}: {mm} mm" for i, mm in offsets.items()), *_repair_lines(repairs),
            *_uncertainty_lines(summary.get("uncertainty")), f"saved in {Path(args.out) / 'summary.json'}"]


def _uncertainty_lines(block: dict | None) -> list[str]:
    """What the data determine, one line per quantity (:func:`dpsi.uncertainty.describe`)."""
    if block is None:
        return []
    if "error" in block:
        return [f"what the data determine could not be measured: {block['error']}"]
    return [f"what the data determine (loss {block['loss_mm']:.1f} mm, tolerance {block['tolerance_mm']:.2g} mm "
            "from its bootstrap spread):", *(f"  {describe(q)}" for q in block["quantities"])]


def _import_release(parser, args) -> list[str]:
    try:
        section = (yaml.safe_load(Path(args.config).read_text()) or {}).get("release")
    except (OSError, yaml.YAMLError) as err:
        parser.error(f"argument --config: cannot read {args.config} ({err})")
    if not isinstance(section, dict) or not {"motions", "effectors"} <= set(section):
        parser.error(f"argument --config: {args.config} has no `release` section with `motions` and `effectors`")
    try:
        tables = ImportTables.from_config(section)
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        parser.error(f"argument --config: {args.config}: malformed `release` section ({err!r})")
    return [json.dumps(record) for record in import_release(args.source, args.out, tables, seed=section.get("seed", 0))]


class _Repairs(logging.Handler):
    """Collects the mesh repairs that reading the shapes made (dpsi.reconstruction.repair logs each)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.made: list[dict] = []

    def emit(self, record: logging.LogRecord) -> None:
        if hasattr(record, "repair"):
            self.made.append(record.repair)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    repairs = _Repairs()
    logging.getLogger("dpsi.repair").addHandler(repairs)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # Taichi prints its start-up line on stdout
            if args.command == "simulate":
                args.params = _params(args.parser, HAND_PICKED, args.param)
                lines = _simulate(args, repairs.made)
            elif args.command == "import-release":
                lines = _import_release(args.parser, args)
            else:
                lines = _identify(args.parser, args, repairs.made)
    except (ValueError, KeyError, OSError, SimulationError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"dpsi {args.command}: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        again = (f"run the same command again to resume from its last completed iteration (kept in {args.out})"
                 if args.command == "identify" else "run the same command again")
        print(f"dpsi {args.command}: interrupted; {again}", file=sys.stderr)
        return 130
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
