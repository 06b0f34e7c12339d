"""Taichi initialisation, done once per process."""

from __future__ import annotations

import os

import taichi as ti
from taichi.lang import impl
from taichi.lang.ast import ast_transformer_utils

_initialised: str | None = None


def source_position(context, node) -> str:
    """Where a kernel's AST ``node`` is, for Taichi's error messages: file, line, function and that line.

    Taichi 1.7 builds this text for every node of every kernel each time a process first calls the kernel,
    even when the compiled kernel then comes from the offline cache, and its own version underlines the node
    with carets re-wrapped by ``textwrap``: about a third of a warm first call of the simulator (0.8 s of
    2.5–3 s for poking-1, docs/benchmarks.md). This plain version names the same place."""
    return (f'File "{context.file}", line {node.lineno + context.lineno_offset}, in {context.func.func.__name__}:\n'
            f"{context.src[node.lineno - 1]}\n")


def ensure_taichi(arch: str = "cpu", threads: int | None = None) -> None:
    """Initialise Taichi for ``arch`` ("cpu" or "cuda") in float64, with the offline kernel cache and, on
    the CPU, ``threads`` threads (None: every CPU this process may run on, which under a batch system is
    what the job was given).

    Later calls with the same arch do nothing (the thread count of the first call stays); asking for
    another arch in the same process is an error, because re-initialising Taichi would throw away every
    compiled kernel and field.
    """
    global _initialised
    if _initialised is not None:
        if arch != _initialised:
            raise RuntimeError(f"Taichi already runs on {_initialised!r} in this process; cannot switch to "
                               f"{arch!r} (start a new process for it)")
        return
    archs = {"cpu": ti.cpu, "cuda": ti.cuda}
    if arch not in archs:
        raise ValueError(f"unknown Taichi arch {arch!r}; use one of {sorted(archs)}")
    options = dict(arch=archs[arch], default_fp=ti.f64, offline_cache=os.environ.get("DPSI_NO_CACHE") is None,
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
    _initialised = arch
