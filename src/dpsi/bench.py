"""Benchmarks that print figures (not timed tests).

    python -m dpsi.bench simulator [--json] [--density 4e7] [--motions poking-1 ...]
    python -m dpsi.bench losses [--json] [--points 3000]

The simulator benchmark runs each motion in a fresh process, so that peak memory is that motion's
own: a lump of clay (6 × 4.8 × 2.8 cm, ~1950 particles at 4e7/m³ like the paper's poking datapoint) filled at the given particle density, the hand-picked
parameters, the motion's own effector. It times the first forward pass (which compiles, unless Taichi's
offline cache already holds the kernels), a second forward pass, the first and a second backward pass.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np

BENCH_MOTIONS = {"poking-1": "round", "poking-shifting-1": "round", "flattening": "cylinder"}
"""Motions of the cost study (SPEC §7.6) and the effector each is run with."""

SIMULATOR_KEYS = ("motion", "particles", "steps", "substeps", "compile_s", "forward_s", "backward_s",
                  "peak_rss_mb")


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_lump_particles(density: float) -> np.ndarray:
    """Particles (m) of the benchmark's clay lump at ``density`` particles/m³."""
    from .reconstruction.filling import fill
    from .shapes import lump

    return fill(lump(semi_axes=(0.03, 0.024), wall=0.012, top=0.028), density)


def measure_simulation(motion: str, density: float, repeat: bool = True) -> dict:
    """Time forward and backward passes of one motion in this process; see the module docstring."""
    from .effectors import by_name
    from .motions import trajectory
    from .parameters import HAND_PICKED
    from .simulation import Scene, Simulator, SimulatorConfig

    particles = bench_lump_particles(density)
    traj = trajectory(motion)
    start = [*(0.5 * (particles[:, :2].min(0) + particles[:, :2].max(0))), particles[:, 2].max()]
    scene = Scene(particles, 1.0 / density, by_name(BENCH_MOTIONS[motion]), traj, start)
    sim = Simulator(SimulatorConfig())
    seed = np.random.default_rng(0).normal(size=particles.shape)

    def timed(call):
        start_time = time.perf_counter()
        call()
        return time.perf_counter() - start_time

    first_forward = timed(lambda: sim.forward(scene, HAND_PICKED))
    first_backward = timed(lambda: sim.backward(seed))
    forward = timed(lambda: sim.forward(scene, HAND_PICKED)) if repeat else first_forward
    backward = timed(lambda: sim.backward(seed)) if repeat else first_backward
    return {"motion": motion, "particles": len(particles), "steps": traj.n_steps, "substeps": sim.substeps,
            "compile_s": max(0.0, first_forward - forward) + max(0.0, first_backward - backward),
            "forward_s": forward, "backward_s": backward, "first_forward_s": first_forward,
            "first_backward_s": first_backward, "peak_rss_mb": peak_rss_mb(), "density": density}


def run_isolated(motion: str, density: float) -> dict:
    """:func:`measure_simulation` in a child process (so its peak memory is its own)."""
    out = subprocess.run([sys.executable, "-m", "dpsi.bench", "_one", motion, str(density)],
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"benchmark of {motion} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def print_table(records: list[dict], keys) -> None:
    widths = [max(len(k), *(len(_fmt(r[k])) for r in records)) for k in keys]
    print("  ".join(k.rjust(w) for k, w in zip(keys, widths)))
    for r in records:
        print("  ".join(_fmt(r[k]).rjust(w) for k, w in zip(keys, widths)))


def _fmt(value) -> str:
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m dpsi.bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    sim = sub.add_parser("simulator", help="forward/backward time and peak memory of the simulator")
    sim.add_argument("--density", type=float, default=4e7, help="particles per m³ (default 4e7)")
    sim.add_argument("--motions", nargs="+", default=list(BENCH_MOTIONS), choices=list(BENCH_MOTIONS))
    sim.add_argument("--json", action="store_true", help="print one JSON list of records")
    losses = sub.add_parser("losses", help="time of the EMD and Chamfer losses with gradient")
    losses.add_argument("--points", type=int, default=3000)
    losses.add_argument("--json", action="store_true")
    one = sub.add_parser("_one")  # internal: one motion in this process
    one.add_argument("motion")
    one.add_argument("density", type=float)
    args = parser.parse_args(argv)

    if args.what == "_one":
        print(json.dumps(measure_simulation(args.motion, args.density)))
    elif args.what == "simulator":
        records = [run_isolated(m, args.density) for m in args.motions]
        if args.json:
            print(json.dumps(records))
        else:
            print_table(records, (*SIMULATOR_KEYS, "first_forward_s", "first_backward_s"))
    else:
        from .losses import bench_emd

        record = bench_emd(args.points)
        print(json.dumps(record) if args.json else
              f"{record['n']} × {record['n']} points: EMD {record['emd_s']:.3f} s, "
              f"Chamfer {record['chamfer_s']:.4f} s (each with gradient)")


if __name__ == "__main__":
    main()
