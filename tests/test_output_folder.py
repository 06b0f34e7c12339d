"""Output folders: a command writes only its own files there, one run at a time."""

import io
import json
import os
import socket
import subprocess
import sys

import pytest

from dpsi import output_folder
from dpsi.output_folder import LOCK_FILE, RECORD_FILE, FolderError, claimed, writable_folder

NAMES = ("log.csv", "summary.json")

HOLD = ("import sys; from dpsi.output_folder import claimed\n"
        "with claimed(sys.argv[1], ['log.csv'], 'dpsi identify'):\n"
        "    print('held', flush=True); sys.stdin.read()\n")


def test_files_of_others_are_kept_and_files_of_other_names_written_beside(tmp_path):
    (tmp_path / "log.csv").write_text("my own log\n")
    (tmp_path / "notes.txt").write_text("mine\n")
    with pytest.raises(FolderError, match=rf"{tmp_path} holds log.csv, which dpsi identify did not write"):
        with claimed(tmp_path, NAMES, "dpsi identify"):
            pytest.fail("claimed a folder holding a foreign log.csv")
    assert (tmp_path / "log.csv").read_text() == "my own log\n"
    assert not (tmp_path / LOCK_FILE).exists()  # released on refusal

    (tmp_path / "log.csv").unlink()
    with claimed(tmp_path, NAMES, "dpsi identify") as folder:
        (folder / "log.csv").write_text("ours\n")
    with claimed(tmp_path, NAMES, "dpsi identify") as folder:  # ours now: may be written again
        (folder / "log.csv").write_text("ours again\n")
    assert json.loads((tmp_path / RECORD_FILE).read_text())["files"] == sorted(NAMES)
    assert (tmp_path / "notes.txt").read_text() == "mine\n" and not (tmp_path / LOCK_FILE).exists()


def test_an_unrecorded_file_recognised_as_ours_is_adopted(tmp_path):
    (tmp_path / "log.csv").write_text("written by an earlier version\n")
    with claimed(tmp_path, NAMES, "dpsi identify", adopt=lambda path: "earlier version" in path.read_text()):
        pass
    assert "log.csv" in json.loads((tmp_path / RECORD_FILE).read_text())["files"]


def test_a_second_run_on_a_held_folder_is_refused_naming_the_holder(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        message = (rf"output folder {tmp_path} is in use by another run \(dpsi identify, process {holder.pid} on "
                   rf"host {socket.gethostname()}, started 20")
        with pytest.raises(FolderError, match=message):
            with claimed(tmp_path, NAMES, "dpsi identify"):
                pytest.fail("two runs held one folder")
    finally:
        holder.communicate("")
    assert holder.returncode == 0 and not (tmp_path / LOCK_FILE).exists()
    with claimed(tmp_path, NAMES, "dpsi identify"):  # free again
        pass


def test_the_lock_of_a_process_that_has_ended_is_taken_over_with_a_note(tmp_path):
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(ended.stdout)
    (tmp_path / LOCK_FILE).write_text(json.dumps({"command": "dpsi identify", "pid": pid,
                                                  "host": socket.gethostname(), "started": "yesterday"}))
    notes = io.StringIO()
    with claimed(tmp_path, NAMES, "dpsi identify", progress=notes):
        assert json.loads((tmp_path / LOCK_FILE).read_text())["pid"] == os.getpid()
    assert f"taking over the lock of {tmp_path} from a run that is no longer running" in notes.getvalue()
    assert f"process {pid} on host" in notes.getvalue() and not (tmp_path / LOCK_FILE).exists()


def test_a_lock_of_another_host_or_an_unreadable_one_is_not_taken_over(tmp_path):
    lock = tmp_path / LOCK_FILE
    lock.write_text(json.dumps({"command": "dpsi identify", "pid": 1, "host": "elsewhere", "started": "today"}))
    with pytest.raises(FolderError, match=r"process 1 on host elsewhere.*if that run is gone, delete"):
        with claimed(tmp_path, NAMES, "dpsi identify"):
            pass
    lock.write_text("{half a lock")
    with pytest.raises(FolderError, match=r"in use by another run \(a run whose lock file cannot be read\)"):
        with claimed(tmp_path, NAMES, "dpsi identify"):
            pass
    assert lock.read_text() == "{half a lock"


def test_a_file_given_as_the_folder_is_named(tmp_path):
    (tmp_path / "run").write_text("")
    with pytest.raises(FolderError, match=rf"output folder {tmp_path / 'run'} is a file; give a folder"):
        writable_folder(tmp_path / "run")
    with pytest.raises(FolderError, match=rf"{tmp_path / 'run' / 'sub'} lies under {tmp_path / 'run'}, which is a file"):
        writable_folder(tmp_path / "run" / "sub")


def test_a_folder_that_cannot_be_written_is_named(tmp_path, monkeypatch):
    """(Made unwritable by failing the first write: permissions do not stop root, who may run the tests.)"""
    def refuse(**kwargs):
        raise PermissionError(13, "Permission denied", os.path.join(kwargs["dir"], ".hidden-temp-file"))

    monkeypatch.setattr(output_folder.tempfile, "mkstemp", refuse)
    with pytest.raises(FolderError, match=rf"^output folder {tmp_path} cannot be written to \(Permission denied\)"):
        writable_folder(tmp_path)
