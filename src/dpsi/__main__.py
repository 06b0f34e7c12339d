"""Command line: ``python -m dpsi`` (or ``dpsi``) with the subcommands ``simulate`` and ``identify``.

Only parsing lives here; the work is done by :mod:`dpsi.prepare`, :mod:`dpsi.identification` and the
simulator. Shapes are point-cloud files (a fused, closed cloud: .ply .pcd .xyz .npy) or watertight
meshes (.obj, or a .ply with faces), in the robot base frame, in metres.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")  # stdout is for results; set before Taichi loads

from dpsi.datapoint import Datapoint
from dpsi.effectors import BUILT_IN, by_name
from dpsi.identification import evaluate, identify
from dpsi.losses import LOSSES
from dpsi.motions import MOTIONS, get_motion, trajectory
from dpsi.parameters import HAND_PICKED, IDENTIFIED, LEVEL1_FIXED, NAMES, UNITS, Parameters, random_initial
from dpsi.pointclouds import read_mesh
from dpsi.prepare import after_targets, assemble, density_holding, fill_particles, reconstruct_state
from dpsi.rawdata import StateSource
from dpsi.simulation import SimulationError, Simulator, SimulatorConfig
from dpsi.uncertainty import describe

DENSITY = 4e7
"""Default particle density (particles/m³), the lowest of SPEC §3.3."""
MAX_PARTICLES = SimulatorConfig().max_particles


def _source(path: str) -> StateSource:
    """A shape file as a state source: a mesh if it has faces (.obj, or .ply with faces), else a fused cloud."""
    if Path(path).suffix.lower() == ".ply":
        try:
            read_mesh(path)
            return StateSource("mesh", (Path(path),))
        except ValueError:
            return StateSource("fused", (Path(path),))
    return StateSource("mesh" if Path(path).suffix.lower() == ".obj" else "fused", (Path(path),))


def _shapes_datapoint(before: str, after: str, motion: str, effector: str, density: float,
                      table_z: float | None, config: SimulatorConfig) -> Datapoint:
    """A datapoint from a before and an after shape: the table is the plane z = ``table_z`` (m), by default
    through the before shape's lowest point; the tip starts at the top centre of the before shape's
    bounding box and follows the resampled ``motion``. Raises naming the file if the before shape does not
    fit the simulator of ``config`` (its box, or its particle capacity at ``density``), or holds fewer
    particles than the after shape's PCD target has points."""
    get_motion(motion)
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
    return assemble(Path(before).stem, motion, shape, particles, density, trajectory(motion), start, targets)


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


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _at_least(minimum: int):
    """An argparse type: an integer ≥ ``minimum``."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer ≥ {minimum}, got {text!r}")
        return value
    return parse


def _shape_options(parser: argparse.ArgumentParser, many: bool) -> None:
    each = " (repeat once per datapoint; a single --motion/--effector applies to all)" if many else ""
    action = "append" if many else "store"
    parser.add_argument("--before", required=True, action=action, metavar="FILE",
                        help="shape before the motion: point cloud or watertight mesh, base frame, m" + each)
    parser.add_argument("--after", required=True, action=action, metavar="FILE",
                        help="shape after the motion, same forms as --before")
    parser.add_argument("--motion", required=True, action=action, choices=sorted(MOTIONS),
                        help="robot motion; the tip starts at the top centre of the before shape")
    parser.add_argument("--effector", required=True, action=action, choices=sorted(BUILT_IN),
                        help="end-effector shape")
    parser.add_argument("--density", type=_positive, default=DENSITY, metavar="D",
                        help=f"particle density in particles/m³ (default {DENSITY:g})")
    parser.add_argument("--table-z", type=_finite, metavar="Z",
                        help="table height in m (default: the before shape's lowest point)")
    parser.add_argument("--max-particles", type=_at_least(1), default=MAX_PARTICLES, metavar="N",
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
                                            "summary.json and state.json to --out; rerunning resumes.")
    ident.set_defaults(parser=ident)
    _shape_options(ident, many=True)
    ident.add_argument("--validate", nargs=4, action="append", default=[],
                       metavar=("BEFORE", "AFTER", "MOTION", "EFFECTOR"),
                       help="a validation datapoint, repeatable (default: validate on the training datapoints)")
    ident.add_argument("--loss", required=True, choices=list(LOSSES), help="training loss")
    ident.add_argument("--level", type=int, default=1, choices=sorted(IDENTIFIED),
                       help="1: identify E, nu, rho, yield_stress (frictions fixed); 2: all six (default 1)")
    ident.add_argument("--seed", type=_at_least(0), default=0, help="seed of the random initial values (default 0)")
    ident.add_argument("--iterations", type=_at_least(1), default=100, help="Adam updates (default 100)")
    ident.add_argument("--initial", choices=["random", "hand-picked"], default="random",
                       help="initial values: uniform random from --seed, or the hand-picked ones (default random)")
    ident.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                       help=_param_help("an initial value overriding --initial"))
    ident.add_argument("--out", required=True, metavar="DIR", help="output folder")
    ident.add_argument("--uncertainty", action=argparse.BooleanOptionalAction, default=True,
                       help="measure at the best iteration what the data determine: an interval for each parameter, "
                            "E/rho, yield_stress/E and the stiffest direction (two gradient passes per identified "
                            "parameter; default on)")
    ident.add_argument("--json", action="store_true", help="print the run's summary (as saved in summary.json, "
                       "its intervals under 'uncertainty') as one JSON object")
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


def _simulate(args) -> list[str]:
    config = SimulatorConfig(max_particles=args.max_particles)
    dp = _shapes_datapoint(args.before, args.after, args.motion, args.effector, args.density, args.table_z, config)
    metrics = evaluate(Simulator(config), dp, args.params)
    result = {"particles": len(dp.particles), **metrics, "params": args.params.as_dict()}
    if args.json:
        return [json.dumps(result)]
    return ([f"particles: {result['particles']}"] + [f"{name}: {value:.3f} mm" for name, value in metrics.items()]
            + [f"{name}: {value:g} {UNITS[name]}" for name, value in result["params"].items()])


def _identify(parser, args) -> list[str]:
    if len(args.after) != len(args.before):
        parser.error(f"argument --after: give one per --before ({len(args.before)}), got {len(args.after)}")
    fixed = sorted({name for name, _ in args.param} & set(LEVEL1_FIXED)) if args.level == 1 else []
    if fixed:
        parser.error(f"argument --param: level 1 keeps {', '.join(fixed)} fixed at {LEVEL1_FIXED}; "
                     "drop the option, or identify the frictions with --level 2")
    base = HAND_PICKED if args.initial == "hand-picked" else random_initial(args.seed, args.level)
    initial = _params(parser, base, args.param)
    config = SimulatorConfig(max_particles=args.max_particles)
    pairs = zip(args.before, args.after, _one_each(parser, args, "motion"), _one_each(parser, args, "effector"))
    training = [_shapes_datapoint(*pair, args.density, args.table_z, config) for pair in pairs]
    validation_set = ([_shapes_datapoint(*quad, args.density, args.table_z, config) for quad in args.validate]
                      or training)
    summary = identify(args.out, args.level, args.loss, training, validation_set, args.seed, args.iterations,
                       initial, simulator=Simulator(config), uncertainty=args.uncertainty)
    if args.json:
        return [json.dumps(summary)]
    best = summary["best"]
    head = ("no iteration has a finite validation height-map distance; final parameters:" if best is None else
            f"best iteration {best['iteration']} (validation height map {best['validation']['heightmap_mm']:.1f} mm):")
    values = (best or summary["final"])["parameters"]
    return [head, *(f"{name}: {value:g} {UNITS[name]}" for name, value in values.items()),
            *_uncertainty_lines(summary.get("uncertainty")), f"saved in {Path(args.out) / 'summary.json'}"]


def _uncertainty_lines(block: dict | None) -> list[str]:
    """What the data determine, one line per quantity (:func:`dpsi.uncertainty.describe`)."""
    if block is None:
        return []
    if "error" in block:
        return [f"what the data determine could not be measured: {block['error']}"]
    return [f"what the data determine (loss {block['loss_mm']:.1f} mm, tolerance {block['tolerance_mm']:.2g} mm "
            "from its bootstrap spread):", *(f"  {describe(q)}" for q in block["quantities"])]


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # Taichi prints its start-up line on stdout
            if args.command == "simulate":
                args.params = _params(args.parser, HAND_PICKED, args.param)
                lines = _simulate(args)
            else:
                lines = _identify(args.parser, args)
    except (ValueError, KeyError, OSError, SimulationError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"dpsi {args.command}: error: {message}", file=sys.stderr)
        return 1
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
