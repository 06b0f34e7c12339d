"""The memory a simulator needs, estimated before it allocates, against the memory this process may use.

Asking Taichi or NumPy for more than the machine has ends in their allocator (a crash, or a request for
1.5 TB) with no word of the setting behind it; :func:`check_fits` refuses beforehand, naming it.
"""

from __future__ import annotations

from pathlib import Path

from .config import SimulationError

GB = 1e9


def _cgroup_room() -> float | None:
    """Bytes this process's control group (cgroup v2, e.g. a batch job's memory limit) may still allocate
    beyond its processes' own memory (its file cache is given back on demand), or None if it sets no
    limit or this system has none."""
    try:
        group = Path("/proc/self/cgroup").read_text().strip().split("::", 1)[1]
        base = Path("/sys/fs/cgroup") / group.lstrip("/")
        limit = (base / "memory.max").read_text().strip()
        if limit == "max":
            return None
        stat = dict(line.split() for line in (base / "memory.stat").read_text().splitlines())
        return float(limit) - float(stat["anon"])
    except (OSError, IndexError, KeyError, ValueError):
        return None


def available_memory() -> float | None:
    """Bytes of memory this process can still allocate without swapping: the kernel's MemAvailable, or less
    if its control group limits it; None if neither can be read (not Linux)."""
    try:
        meminfo = dict(line.split(":", 1) for line in Path("/proc/meminfo").read_text().splitlines())
        free = float(meminfo["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError, IndexError):
        free = None
    room = _cgroup_room()
    known = [b for b in (free, room) if b is not None]
    return min(known) if known else None


def check_fits(need: float, what: str, advice: str) -> None:
    """Raise :class:`SimulationError` if ``need`` bytes (for ``what``) exceed the :func:`available_memory`,
    saying what to change (``advice``)."""
    available = available_memory()
    if available is not None and need > available:
        raise SimulationError(f"the simulator would need {need / GB:.3g} GB for {what}, more than the "
                              f"{available / GB:.3g} GB of memory available here; {advice}")


__all__ = ["available_memory", "check_fits"]
