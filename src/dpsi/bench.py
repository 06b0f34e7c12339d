"""Benchmarks that print figures (not timed tests), and the measurement behind the cost table.

    python -m dpsi.bench simulator [--json] [--density 4e7] [--motions poking-1 ...] [--arch cuda]
    python -m dpsi.bench scaling [--json] [--density 3.3e8] [--motion poking-1]
    python -m dpsi.bench losses [--json] [--points 3000]

The simulator benchmark runs each motion in a fresh process, so that peak memory is that motion's
own: a lump of clay (6 × 4.8 × 2.8 cm, ~1950 particles at 4e7/m³ like the paper's poking datapoint)
filled at the given particle density, the hand-picked parameters, the motion's own effector. It times the
first forward pass (which compiles, unless Taichi's offline cache already holds the kernels), the first
backward pass, then forward + backward iterations, and says whether Taichi's offline cache was warm.
Below its table it prints each figure beside its target (:data:`TARGETS`, for the CPU of the development
machine or for an H100 GPU with ``--arch cuda``).

The scaling benchmark times one forward + backward of a larger lump (~17 000 particles at 3.3e8/m³) on the
CPU, each in a fresh process: on one thread, on every CPU the process may use with the default loops
(scatters on one thread), and on every CPU with every loop parallel (``serial: false``: the transfers
gather), and prints each speed-up over one thread beside the target for a 16-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .arguments import at_least, positive, simulator_settings
from .progress import Progress

BENCH_MOTIONS = {"poking-1": "round", "poking-shifting-1": "round", "flattening": "cylinder"}
"""Motions of the cost study (SPEC §7.6) and the effector each is run with."""

TARGETS = {
    "cpu": {"poking-1": 4.0, "poking-shifting-1": 7.0, "flattening": 18.0, "cold": 20.0, "warm": 3.0,
            "flattening_mib": 1024.0},
    "cuda": {"poking-1": 1.0, "flattening": 5.0, "large": 3.0, "backward_ratio": 2.0, "cold": 20.0, "warm": 3.0},
}
"""Targets of the simulator issue (s, MiB): forward + backward per motion at ~2000 particles; on the GPU
also at ≥ 60 000 particles ("large") and the backward pass at most this many times the forward; the extra
time of a new process's first forward + backward with a cold or warm kernel cache; the peak memory of
flattening on the CPU."""

SCALING_TARGET = 4.0
"""Speed-up over one thread that every core of a 16-core machine should give at ~16 000 particles."""

SCALING_SETTINGS = {"one thread": {"threads": 1}, "every thread": {},
                    "every thread, every loop parallel": {"serial": False}}
"""The runs of the scaling benchmark: SimulatorConfig settings by label."""

LARGE_SCENE = 60000
"""Particles from which the GPU's large-scene target applies (the issue's 65k)."""

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


def timed(call) -> float:
    """Wall-clock time (s) of ``call()``."""
    start = time.perf_counter()
    call()
    return time.perf_counter() - start


def taichi_cache_folder() -> Path | None:
    """Folder of Taichi's offline kernel cache in this (initialised) process; None when the cache is off."""
    from taichi.lang import impl

    config = impl.current_cfg()
    return Path(config.offline_cache_file_path) if config.offline_cache else None


def cached_kernels(folder: Path | None) -> frozenset[str]:
    """Names of the compiled-kernel files in the offline cache ``folder`` (empty when there is none)."""
    return frozenset(p.name for p in folder.glob("*.tic")) if folder and folder.is_dir() else frozenset()


def finish_taichi(folder: Path | None, before: frozenset[str]) -> str:
    """Finalise Taichi — which writes the kernels this process compiled to the offline cache — and say how
    the cache served the process: "off", "warm" (no kernel compiled: all came from the cache) or "cold"
    (some kernels compiled). Taichi cannot be used in this process afterwards. Another Taichi process
    ending meanwhile and adding kernels to the same cache makes a warm run look cold."""
    import taichi as ti

    ti.reset()
    if folder is None:
        return "off"
    return "cold" if cached_kernels(folder) - before else "warm"


def measure_simulation(motion: str, density: float, iterations: int, config) -> dict:
    """Time and measure one motion on the benchmark lump in this process (see the module docstring).

    Order: the peak resident memory before the simulator exists (``base_peak_rss_mb``, MiB: Python,
    Taichi, and open3d and pymeshlab for filling the lump), the first (compiling) forward pass, the peak
    resident memory so far (``forward_peak_rss_mb``,
    MiB: before any backward pass), the first backward pass, then ``iterations`` forward + backward
    iterations (each with the same seed gradient, no loss), then the peak memory of the whole process
    (``peak_rss_mb``, MiB). ``forward_s`` and ``backward_s`` are means over the iterations (s),
    ``iteration_s`` the time of each iteration (s), ``compile_s`` how much longer the first passes took.
    ``config``: the :class:`~dpsi.simulation.SimulatorConfig`.

    Finalises Taichi at the end to learn whether its offline cache was warm (``taichi_cache``), so this
    must be the last Taichi work of the process."""
    from .effectors import by_name
    from .motions import trajectory
    from .parameters import HAND_PICKED
    from .simulation import Scene, Simulator

    particles = bench_lump_particles(density)
    traj = trajectory(motion)
    start = [*(0.5 * (particles[:, :2].min(0) + particles[:, :2].max(0))), particles[:, 2].max()]
    scene = Scene(particles, 1.0 / density, by_name(BENCH_MOTIONS[motion]), traj, start)
    base_rss = peak_rss_mb()
    sim = Simulator(config)
    cache = taichi_cache_folder()
    kernels_before = cached_kernels(cache)
    seed = np.random.default_rng(0).normal(size=particles.shape)
    forward_pass = lambda: sim.forward(scene, HAND_PICKED)  # noqa: E731
    backward_pass = lambda: sim.backward(seed)  # noqa: E731

    first_forward = timed(forward_pass)
    forward_rss = peak_rss_mb()
    first_backward = timed(backward_pass)
    passes = np.array([(timed(forward_pass), timed(backward_pass)) for _ in range(iterations)])
    forward, backward = map(float, passes.mean(axis=0))
    record = {"motion": motion, "density": density, "particles": len(particles), "steps": traj.n_steps,
              "substeps": sim.substeps, "first_forward_s": first_forward, "first_backward_s": first_backward,
              "forward_s": forward, "backward_s": backward,
              "compile_s": max(0.0, first_forward - forward) + max(0.0, first_backward - backward),
              "iteration_s": passes.sum(axis=1).tolist(), "base_peak_rss_mb": base_rss,
              "forward_peak_rss_mb": forward_rss, "peak_rss_mb": peak_rss_mb()}
    return {**record, "taichi_cache": finish_taichi(cache, kernels_before)}


def run_isolated(motion: str, density: float, iterations: int = 1, simulator: dict | None = None) -> dict:
    """:func:`measure_simulation` in a child process that runs nothing else, so that its peak memory is the
    measurement's own. ``simulator``: :class:`~dpsi.simulation.SimulatorConfig` settings (defaults if None)."""
    out = subprocess.run([sys.executable, "-m", "dpsi.bench", "_one", motion, str(density), "--iterations",
                          str(iterations), "--simulator", json.dumps(simulator or {})], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"benchmark of {motion} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure_scaling(motion: str, density: float) -> list[dict]:
    """One forward + backward of ``motion`` on the benchmark lump at ``density`` for each of
    :data:`SCALING_SETTINGS` (fresh processes), each record with its ``label``, the CPUs used
    (``threads``) and its ``speedup`` over the first (one thread)."""
    capacity = {"max_particles": len(bench_lump_particles(density))}
    cpus = len(os.sched_getaffinity(0))
    records = [{**run_isolated(motion, density, simulator={**capacity, **settings}), "label": label,
                "threads": settings.get("threads", cpus)} for label, settings in SCALING_SETTINGS.items()]
    one = records[0]["forward_s"] + records[0]["backward_s"]
    return [{**r, "speedup": one / (r["forward_s"] + r["backward_s"])} for r in records]


def scaling_lines(records: list[dict]) -> list[str]:
    """The scaling records as lines of text, the best speed-up beside :data:`SCALING_TARGET`."""
    lines = [f"{r['label']:<36} {r['threads']:>3} threads  forward {r['forward_s']:7.2f} s  backward "
             f"{r['backward_s']:7.2f} s  speed-up {r['speedup']:5.2f}" for r in records]
    best, cpus = max(r["speedup"] for r in records[1:]), records[1]["threads"]
    verdict = "met" if best >= SCALING_TARGET else "NOT met"
    lines.append(f"{records[0]['particles']} particles, best speed-up {best:.2f} on {cpus} CPUs: target ≥ "
                 f"{SCALING_TARGET:g} on 16 cores {verdict if cpus >= 16 else 'not measurable here'}")
    return lines


def target_lines(records: list[dict], arch: str) -> list[str]:
    """Each measured figure of ``records`` beside its target for ``arch``: one line each, ending in
    "met" or "NOT met"."""
    goals = TARGETS[arch]
    rows = []
    for r in records:
        name, total = r["motion"], r["forward_s"] + r["backward_s"]
        if arch == "cuda" and r["particles"] >= LARGE_SCENE:
            rows.append((f"{name} at {r['particles']} particles: forward + backward (s)", total, goals["large"]))
        elif name in goals:
            rows.append((f"{name}: forward + backward (s)", total, goals[name]))
        if "backward_ratio" in goals:
            rows.append((f"{name}: backward / forward", r["backward_s"] / r["forward_s"], goals["backward_ratio"]))
        if r["taichi_cache"] in ("cold", "warm", "off"):
            cache = "warm" if r["taichi_cache"] == "warm" else "cold"
            rows.append((f"{name}: first forward + backward beyond later ones, {cache} kernel cache (s)",
                         r["compile_s"], goals[cache]))
        if name == "flattening" and "flattening_mib" in goals:
            rows.append((f"{name}: peak memory (MiB)", r["peak_rss_mb"], goals["flattening_mib"]))
    return [f"{label:<72} {value:8.2f}  target ≤ {goal:g}  {'met' if value <= goal else 'NOT met'}"
            for label, value, goal in rows]


def print_table(records: list[dict], keys) -> None:
    widths = [max(len(k), *(len(_fmt(r[k])) for r in records)) for k in keys]
    print("  ".join(k.rjust(w) for k, w in zip(keys, widths)))
    for r in records:
        print("  ".join(_fmt(r[k]).rjust(w) for k, w in zip(keys, widths)))


def _fmt(value) -> str:
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dpsi.bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    sim = sub.add_parser("simulator", help="forward/backward time and peak memory of the simulator")
    sim.add_argument("--density", type=positive, default=4e7, help="particles per m³ (default 4e7)")
    sim.add_argument("--motions", nargs="+", default=list(BENCH_MOTIONS), choices=list(BENCH_MOTIONS))
    sim.add_argument("--json", action="store_true", help="print one JSON list of records")
    sim.add_argument("--arch", choices=sorted(TARGETS), default="cpu", help="where Taichi runs (default cpu)")
    scaling = sub.add_parser("scaling", help="speed-up of every CPU thread over one on a larger scene")
    scaling.add_argument("--density", type=positive, default=3.3e8, help="particles per m³ (default 3.3e8)")
    scaling.add_argument("--motion", default="poking-1", choices=list(BENCH_MOTIONS))
    scaling.add_argument("--json", action="store_true", help="print one JSON list of records")
    losses = sub.add_parser("losses", help="time of the EMD and Chamfer losses with gradient")
    losses.add_argument("--points", type=at_least(1), default=3000, help="points of each cloud (default 3000)")
    losses.add_argument("--json", action="store_true")
    one = sub.add_parser("_one")  # internal: one motion in this process
    one.add_argument("motion")
    one.add_argument("density", type=positive)
    one.add_argument("--iterations", type=at_least(1), default=1)
    one.add_argument("--simulator", type=simulator_settings(), default={}, help="SimulatorConfig settings as JSON")
    args = parser.parse_args(argv)
    try:
        _run(args)
    except (ValueError, RuntimeError, OSError) as err:
        print(f"{parser.prog}: error: {err}", file=sys.stderr)
        return 1
    return 0


def _run(args) -> None:
    """Run the benchmark ``args`` name and print its figures."""
    if args.what == "_one":
        from .simulation import SimulatorConfig

        config = SimulatorConfig(**args.simulator)
        print(json.dumps(measure_simulation(args.motion, args.density, args.iterations, config)))
    elif args.what == "simulator":
        settings = {"arch": args.arch}
        records = []
        with Progress(len(args.motions), "benchmark") as bar:
            for k, motion in enumerate(args.motions, 1):
                records.append({**run_isolated(motion, args.density, simulator=settings), **settings})
                bar.update(k, f"{motion}: forward {records[-1]['forward_s']:.2f} s, "
                              f"backward {records[-1]['backward_s']:.2f} s")
        if args.json:
            print(json.dumps(records))
        else:
            print_table(records, (*SIMULATOR_KEYS, "first_forward_s", "first_backward_s", "taichi_cache"))
            print(f"\ntargets ({args.arch}):")
            print("\n".join(target_lines(records, args.arch)))
    elif args.what == "scaling":
        records = measure_scaling(args.motion, args.density)
        print(json.dumps(records) if args.json else "\n".join(scaling_lines(records)))
    else:
        from .losses import bench_emd

        record = bench_emd(args.points)
        print(json.dumps(record) if args.json else
              f"{record['n']} × {record['n']} points: EMD {record['emd_s']:.3f} s, "
              f"Chamfer {record['chamfer_s']:.4f} s (each with gradient)")


if __name__ == "__main__":
    sys.exit(main())
