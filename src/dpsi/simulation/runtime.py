"""Taichi initialisation, done once per process."""

from __future__ import annotations

import os

import taichi as ti
from taichi.lang import impl
from taichi.lang.ast import ast_transformer_utils

_initialised: tuple[str, str] | None = None


def source_position(context, node) -> str:
    """Where a kernel's AST ``node`` is, for Taichi's error messages: file, line, function and that line.

    Taichi 1.7 builds this text for every node of every kernel each time a process first calls the kernel,
    even when the compiled kernel then comes from the offline cache, and its own version underlines the node
    with carets re-wrapped by ``textwrap``: about a third of a warm first call of the simulator (0.8 s of
    2.5–3 s for poking-1, docs/benchmarks.md). This plain version names the same place."""
    return (f'File "{context.file}", line {node.lineno + context.lineno_offset}, in {context.func.func.__name__}:\n'
            f"{context.src[node.lineno - 1]}\n")


def ensure_taichi(arch: str = "cpu", precision: str = "f64", threads: int | None = None) -> None:
    """Initialise Taichi for ``arch`` ("cpu" or "cuda") with floating-point ``precision`` ("f64" or
    "f32"), the offline kernel cache and, on the CPU, ``threads`` threads (None: every CPU this process
    may run on, which under a batch system is what the job was given).

    Later calls with the same arch and precision do nothing (the thread count of the first call stays);
    asking for another arch or precision in the same process is an error, because re-initialising Taichi
    would throw away every compiled kernel and field.
    """
    global _initialised
    if _initialised is not None:
        if (arch, precision) != _initialised:
            raise RuntimeError(f"Taichi already runs on {_initialised[0]!r} in {_initialised[1]} in this process; "
                               f"cannot switch to {arch!r} in {precision} (start a new process for it)")
        return
    archs = {"cpu": ti.cpu, "cuda": ti.cuda}
    if arch not in archs:
        raise ValueError(f"unknown Taichi arch {arch!r}; use one of {sorted(archs)}")
    floats = {"f64": ti.f64, "f32": ti.f32}
    if precision not in floats:
        raise ValueError(f"unknown precision {precision!r}; use one of {sorted(floats)}")
    options = dict(arch=archs[arch], default_fp=floats[precision], offline_cache=os.environ.get("DPSI_NO_CACHE") is None,
                   log_level=ti.WARN, random_seed=0)
    if arch == "cpu":
        options["cpu_max_num_threads"] = threads or len(os.sched_getaffinity(0))
    cache = os.environ.get("DPSI_TAICHI_CACHE")
    if cache:
        options["offline_cache_file_path"] = cache
    if ti.__version__[:2] == (1, 7):  # the attributes source_position reads are Taichi 1.7's
        ast_transformer_utils.ASTTransformerContext.get_pos_info = source_position
    ti.init(**options)
    if impl.current_cfg().arch != archs[arch]:
        raise RuntimeError(f"Taichi found no usable {arch!r} device here and fell back to "
                           f"{impl.current_cfg().arch.name}; run on a machine with one, or ask for 'cpu'")
    _initialised = (arch, precision)
