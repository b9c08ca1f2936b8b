"""Outputs never clobber or mix: only regular files and folders are written (a device, FIFO or
socket is refused), every write goes through a temporary file and a rename, an OS error names
the file being written, and one run owns an ``--out`` folder at a time (a lock; a stale one is
taken over and said so)."""
from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main
from compensation.app.outputs import LOCK_NAME, FolderLock, owned_folder
from compensation.app.validate import UsageError
from errormap import io as eio


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 2
    return rc, out.getvalue(), err.getvalue()


def one_line(rc, err, *needles):
    lines = [ln for ln in err.splitlines() if "error" in ln.lower()]  # progress lines before it are fine
    assert rc == 2 and "Traceback" not in err and len(lines) == 1, (rc, err)
    assert len(lines[0]) <= MAX_ERROR_CHARS + 40
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def elements(tmp_path_factory, grinder):
    from errormap.chain_truth import make_chain_truth
    d = tmp_path_factory.mktemp("el")
    return make_chain_truth(grinder, 3).elements.save(d / "elements.json")


@pytest.fixture
def points(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("x_mm,z_mm,a_deg\n10,20,30\n11,21,31\n")
    return p


# --- special files -------------------------------------------------------------------------------
def _special(tmp_path, kind):
    if kind == "fifo":
        p = tmp_path / "fifo"
        os.mkfifo(p)
        return p, "FIFO"
    if kind == "socket":
        p = tmp_path / "sock"
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(p))
        return p, "socket"
    if kind == "devnull":
        return Path("/dev/null"), "character device"
    link = tmp_path / "link"
    link.symlink_to("/dev/null")
    return link, "character device (through a symbolic link)"


@pytest.mark.parametrize("kind", ["devnull", "fifo", "socket", "link"])
def test_predict_out_onto_a_special_file_is_refused(tmp_path, elements, points, kind):
    """``predict --out /dev/null`` (as root) used to replace the device with a regular file."""
    target, what = _special(tmp_path, kind)
    mode = os.lstat(target).st_mode
    rc, _, err = run_cli(["predict", points, "--model", elements, "--out", target])
    one_line(rc, err, str(target), what, "--out")
    assert os.lstat(target).st_mode == mode  # untouched
    assert not [p for p in target.parent.iterdir() if p.name.startswith(f".{target.name}.")]


@pytest.mark.parametrize("kind", ["fifo", "link"])
def test_atomic_write_refuses_a_special_file_inside_an_output_folder(tmp_path, kind):
    """The writer itself checks (an ``--out`` folder holding a FIFO at an output's name)."""
    target, what = _special(tmp_path, kind)
    with pytest.raises(eio.InputError, match=what.replace("(", r"\(").replace(")", r"\)")):
        with eio.atomic_write(target, "w") as fh:
            fh.write("x")
    assert os.path.exists("/dev/null") and not Path("/dev/null").is_file()
    assert [p.name for p in tmp_path.iterdir()] == [target.name]  # no temporary file left


def test_out_folder_that_is_a_special_file_is_refused(tmp_path, points):
    fifo, _ = _special(tmp_path, "fifo")
    rc, _, err = run_cli(["simulate", "--out", fifo, "--checks", "20"])
    one_line(rc, err, str(fifo), "FIFO")


def test_full_disk_names_the_file_being_written(tmp_path, elements, points, monkeypatch):
    """ENOSPC during a write was "error:: No space left on device", naming no file."""
    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(eio.os, "fsync", full)
    out = tmp_path / "pred.csv"
    rc, _, err = run_cli(["predict", points, "--model", elements, "--out", out])
    # the sidecar (provenance, NAME.meta.json) is written first: the refusal names it, the file being written
    line = one_line(rc, err, str(tmp_path / "pred.meta.json"), "No space left on device")
    assert "error::" not in line
    assert list(tmp_path.iterdir()) == [points]  # neither the output nor its temporary file


# --- the lock ------------------------------------------------------------------------------------
def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _write_lock(folder: Path, pid: int, host=None, command="diagnose"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / LOCK_NAME).write_text(json.dumps({"pid": pid, "host": host or socket.gethostname(),
                                                "command": command, "started_utc": "2026-01-01T00:00:00Z"}))


def test_a_held_lock_refuses_a_second_run_naming_the_holder(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        _write_lock(tmp_path / "sim", holder.pid, command="simulate")
        rc, _, err = run_cli(["simulate", "--out", tmp_path / "sim", "--checks", "20"])
        one_line(rc, err, f"in use by volcomp simulate (pid {holder.pid} on {socket.gethostname()}",
                 str(tmp_path / "sim"))
    finally:
        holder.kill()
        holder.wait()
    assert [p.name for p in (tmp_path / "sim").iterdir()] == [LOCK_NAME]  # nothing written


def test_a_lock_from_another_host_is_never_taken_over(tmp_path):
    _write_lock(tmp_path / "o", 1, host="another-host.example")
    with pytest.raises(UsageError, match="another-host.example.*remove"):
        FolderLock(tmp_path / "o", "simulate").acquire()


def test_a_stale_lock_is_taken_over_and_said(tmp_path, capsys):
    pid = _dead_pid()
    _write_lock(tmp_path / "sim", pid, command="simulate")
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--checks", "20"]) == 0
    err = capsys.readouterr().err
    assert f"taking over the stale lock of volcomp simulate (pid {pid}" in err
    names = sorted(p.name for p in (tmp_path / "sim").iterdir())
    assert LOCK_NAME not in names and "checks.csv" in names  # released after the run


def test_an_unreadable_lock_is_refused_naming_it(tmp_path):
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / LOCK_NAME).write_text("")
    with pytest.raises(UsageError, match=f"locked by .*{LOCK_NAME}.*cannot be read"):
        FolderLock(tmp_path / "o", "diagnose").acquire()


def test_owned_folder_releases_the_lock_and_removes_a_folder_left_empty(tmp_path):
    with pytest.raises(ValueError):
        with owned_folder(tmp_path / "a" / "b", "simulate"):
            assert (tmp_path / "a" / "b" / LOCK_NAME).is_file()
            raise ValueError("refused")
    assert not (tmp_path / "a").exists()  # a refused run leaves no folder
    with owned_folder(tmp_path / "c", "simulate") as d:
        (d / "x.txt").write_text("x")
    assert [p.name for p in (tmp_path / "c").iterdir()] == ["x.txt"]


def test_a_run_refused_by_a_lock_never_removes_the_other_runs_folder(tmp_path, monkeypatch):
    """Two runs into a folder that did not exist: both see it absent, the first takes the lock; the
    refused second must not remove the folder it thought it had created (it holds the first's files)."""
    from compensation.app import outputs
    target = tmp_path / "new" / "out"

    def raced(self):
        (self.folder / LOCK_NAME).write_text("{}")       # the first run's lock and output, meanwhile
        (self.folder / "first.csv").write_text("x\n")
        raise UsageError("in use")
    monkeypatch.setattr(outputs.FolderLock, "acquire", raced)
    with pytest.raises(UsageError):
        with owned_folder(target, "diagnose"):
            pass
    assert sorted(p.name for p in target.iterdir()) == [LOCK_NAME, "first.csv"]


def test_an_error_caused_by_ctrl_c_cleans_like_ctrl_c(tmp_path):
    """A Ctrl-C that surfaces as another error (an import's 'initialization failed' with the
    KeyboardInterrupt as its cause) removes what the run added, as a KeyboardInterrupt does."""
    d = tmp_path / "o"
    d.mkdir()
    (d / "old.txt").write_text("old")
    with pytest.raises(ImportError):
        with owned_folder(d, "simulate") as out:
            (out / "new").mkdir()
            (out / "new" / "half.csv").write_text("x")
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt as exc:
                raise ImportError("initialization failed") from exc
    assert sorted(p.name for p in d.iterdir()) == ["old.txt"]
    with pytest.raises(ValueError):  # an ordinary error keeps what was written (the command's own message says why)
        with owned_folder(d, "simulate") as out:
            (out / "kept.txt").write_text("x")
            raise ValueError("refused")
    assert sorted(p.name for p in d.iterdir()) == ["kept.txt", "old.txt"]
