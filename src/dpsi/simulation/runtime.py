"""Taichi initialisation, done once per process."""

from __future__ import annotations

import os

import taichi as ti

_initialised_arch: str | None = None


def ensure_taichi(arch: str = "cpu", threads: int | None = None) -> None:
    """Initialise Taichi for ``arch`` ("cpu" or "cuda") with float64 and the offline kernel cache.

    Later calls with the same arch do nothing; asking for another arch in the same process is an
    error, because re-initialising Taichi would throw away every compiled kernel and field.
    """
    global _initialised_arch
    if _initialised_arch is not None:
        if arch != _initialised_arch:
            raise RuntimeError(f"Taichi already runs on {_initialised_arch!r} in this process; "
                               f"cannot switch to {arch!r}")
        return
    archs = {"cpu": ti.cpu, "cuda": ti.cuda}
    if arch not in archs:
        raise ValueError(f"unknown Taichi arch {arch!r}; use one of {sorted(archs)}")
    options = dict(arch=archs[arch], default_fp=ti.f64, offline_cache=os.environ.get("DPSI_NO_CACHE") is None, log_level=ti.WARN,
                   random_seed=0)
    if arch == "cpu":
        options["cpu_max_num_threads"] = threads or os.cpu_count() or 1
    cache = os.environ.get("DPSI_TAICHI_CACHE")
    if cache:
        options["offline_cache_file_path"] = cache
    ti.init(**options)
    _initialised_arch = arch
