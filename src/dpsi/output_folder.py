"""Output folders a command owns: it writes only its own files there, never over anyone else's, and one
run at a time.

Before a command writes (or simulates) anything it claims its folder with :func:`claimed`:

- the folder is created if missing and must be a writable folder (not a file);
- a lock file (:data:`LOCK_FILE`) holds the claiming process's id, host and start time; a second run on
  the same folder is refused, naming them. A lock left by a process of this host that is no longer
  running (killed, or its machine restarted) is taken over with a note; one of another host cannot be
  checked from here and stays until removed by hand;
- an ownership record (:data:`RECORD_FILE`) lists the files the command writes there. A file of one of
  those names that the record does not list was written by someone else (a user's own ``log.csv``), and
  the claim is refused, naming it; files of other names are left alone, so a command writes beside
  them, never over them.

The lock is released when the claim ends, also on an error or Ctrl-C.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import socket
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TextIO

from .files import atomic_output

LOCK_FILE = ".dpsi.lock"
RECORD_FILE = ".dpsi-files.json"


class FolderError(ValueError):
    """An output folder that cannot be used: not a folder, not writable, in use by another run, or
    holding files the command did not write."""


def writable_folder(folder: str | os.PathLike) -> Path:
    """``folder`` as a Path, created if missing; :class:`FolderError` naming it if it is (under) a file or
    cannot be written to."""
    folder = Path(folder)
    for path in (folder, *folder.parents):
        if path.exists() and not path.is_dir():
            where = "is a file" if path == folder else f"lies under {path}, which is a file"
            raise FolderError(f"output folder {folder} {where}; give a folder (it is created if missing)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".dpsi-probe.")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise FolderError(f"output folder {folder} cannot be written to ({err.strerror}); "
                          "choose a folder you may write to") from None
    return folder


def _process_start(pid: int) -> str | None:
    """When process ``pid`` of this host started (clock ticks since boot, from /proc), or None if it is
    not running or this system has no /proc: with the pid it tells a running process from a later one
    that reuses its id."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def _running(holder: dict) -> bool:
    """Whether the process of lock record ``holder`` (of this host) is still running."""
    try:
        os.kill(int(holder["pid"]), 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: running
        pass
    started = _process_start(int(holder["pid"]))
    return holder.get("process_start") is None or started is None or started == holder["process_start"]


def _describe(holder: dict) -> str:
    if "pid" not in holder:
        return "a run whose lock file cannot be read"
    return (f"{holder.get('command', 'a dpsi command')}, process {holder.get('pid')} on host {holder.get('host')}, "
            f"started {holder.get('started')}")


def _read_lock(lock: Path) -> dict | None:
    """The lock record, or None if the lock is gone; an unreadable one counts as held by an unknown process."""
    try:
        holder = json.loads(lock.read_text())
        return holder if isinstance(holder, dict) else {}
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {}


def _lock(folder: Path, command: str, note: Callable[[str], None]) -> dict:
    """Create the folder's lock for this process (atomically: a complete file linked into place) and
    return its record; take over a stale one of this host, refuse a live or foreign one."""
    lock = folder / LOCK_FILE
    me = {"command": command, "pid": os.getpid(), "host": socket.gethostname(),
          "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
          "process_start": _process_start(os.getpid())}
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f"{LOCK_FILE}.")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(me))
        for _ in range(2):
            try:
                os.link(tmp, lock)
                return me
            except FileExistsError:
                holder = _read_lock(lock)
                if holder is None:
                    continue  # released meanwhile
                if holder.get("host") != me["host"] or "pid" not in holder or _running(holder):
                    raise FolderError(f"output folder {folder} is in use by another run ({_describe(holder)}); "
                                      f"wait for it to end or use another folder (if that run is gone, delete "
                                      f"{lock})") from None
                note(f"taking over the lock of {folder} from a run that is no longer running ({_describe(holder)})")
                lock.unlink(missing_ok=True)
    finally:
        os.unlink(tmp)
    raise FolderError(f"output folder {folder}: could not take its lock {lock}; another run is starting there")


def _release(folder: Path, me: dict) -> None:
    """Remove the lock if it is still this process's."""
    lock = folder / LOCK_FILE
    if _read_lock(lock) == me:
        lock.unlink(missing_ok=True)


def _recorded(folder: Path) -> set[str]:
    try:
        record = json.loads((folder / RECORD_FILE).read_text())
        return set(record["files"])
    except FileNotFoundError:
        return set()
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise FolderError(f"{folder / RECORD_FILE} is not a readable record of the files dpsi wrote there ({err}); "
                          "delete it if the folder holds no files of yours by those names") from None


def _claim_files(folder: Path, names: Sequence[str], command: str, adopt: Callable[[Path], bool]) -> None:
    """Refuse if one of ``names`` exists in ``folder`` without being recorded as ours (or adopted, see
    :func:`claimed`); else record them all as ours."""
    recorded = _recorded(folder)
    foreign = [n for n in names if n not in recorded and (folder / n).exists() and not adopt(folder / n)]
    if foreign:
        raise FolderError(f"output folder {folder} holds {', '.join(foreign)}, which {command} did not write; "
                          f"it writes {', '.join(names)} there and never over files of others: move "
                          f"{'it' if len(foreign) == 1 else 'them'} away or use another folder")
    if not set(names) <= recorded:
        with atomic_output(folder / RECORD_FILE) as tmp:
            tmp.write_text(json.dumps({"files": sorted(recorded | set(names))}) + "\n")


@contextlib.contextmanager
def claimed(folder: str | os.PathLike, names: Sequence[str], command: str, progress: TextIO | None = None,
            adopt: Callable[[Path], bool] = lambda path: False) -> Iterator[Path]:
    """Hold ``folder`` (created if missing) for a run of ``command`` (e.g. "dpsi identify") that writes the
    files ``names`` there, and yield it as a Path (see the module doc). ``adopt``: whether an unrecorded
    file of one of the names is ours all the same (a file of an earlier dpsi version, recognised by its
    content). Notes (a stale lock taken over) go to ``progress`` (default stderr). Raises
    :class:`FolderError`."""
    folder = writable_folder(folder)
    stream = progress if progress is not None else sys.stderr
    me = _lock(folder, command, lambda text: print(f"{command}: {text}", file=stream, flush=True))
    try:
        _claim_files(folder, names, command, adopt)
        yield folder
    finally:
        _release(folder, me)


__all__ = ["LOCK_FILE", "RECORD_FILE", "FolderError", "writable_folder", "claimed"]
