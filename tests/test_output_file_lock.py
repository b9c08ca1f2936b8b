"""One run owns a single-file ``--out`` at a time (``predict --out f.csv``): a lock beside it,
``f.csv.volcomp.lock``, with the folder lock's rules (compensation/app/outputs.py owned_file):
a second run is refused naming the holder, a dead local holder's lock is taken over and said, the
lock goes when the run ends, and Ctrl-C leaves no file the run added."""
from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main
from compensation.app.outputs import file_lock_path, is_lock, owned_file, owned_output

ROOT = Path(__file__).resolve().parents[1]


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def elements(tmp_path_factory):
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    d = tmp_path_factory.mktemp("el")
    return make_chain_truth(load_machine("grinder"), 3).elements.save(d / "elements.json")


@pytest.fixture
def points(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("x_mm,z_mm,a_deg\n10,20,30\n11,21,31\n")
    return p


def _lock(target: Path, pid: int, host=None, command="predict"):
    file_lock_path(target).write_text(json.dumps({"pid": pid, "host": host or socket.gethostname(),
                                                  "command": command, "started_utc": "2026-01-01T00:00:00Z"}))


def test_the_lock_lies_beside_the_file():
    assert file_lock_path(Path("/a/b/f.csv")) == Path("/a/b/f.csv.volcomp.lock")
    assert is_lock("/a/b/f.csv.volcomp.lock") and is_lock("/a/.volcomp.lock") and not is_lock("/a/f.csv")


def test_a_second_run_on_a_held_file_is_refused_naming_the_holder(tmp_path, elements, points):
    """The holder is another live process (a second volcomp run as seen from this one)."""
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    out = tmp_path / "f.csv"
    try:
        _lock(out, holder.pid)
        rc, _, err = run_cli(["predict", "--model", elements, points, "--out", out])
    finally:
        holder.kill()
        holder.wait()
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert rc == 2 and len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS, err
    assert f"in use by volcomp predict (pid {holder.pid} on {socket.gethostname()}" in lines[0]
    assert not out.exists() and file_lock_path(out).is_file()   # nothing written, the holder's lock kept


def test_two_concurrent_processes_one_owns_the_file(tmp_path, elements, points):
    """A real second process: while this one holds the file (owned_file), `volcomp predict` in a
    subprocess onto the same --out is refused (exit 2) and writes nothing."""
    out = tmp_path / "f.csv"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    with owned_file(out, "predict"):
        p = subprocess.run([sys.executable, "-m", "compensation.app.cli", "predict", "--model", str(elements),
                            str(points), "--out", str(out)], capture_output=True, text=True, env=env, timeout=120)
        assert p.returncode == 2, p.stderr
        assert f"in use by volcomp predict (pid {os.getpid()}" in p.stderr and "Traceback" not in p.stderr
        assert not out.exists()
    assert not file_lock_path(out).exists()   # released


def test_a_stale_file_lock_is_taken_over_and_said(tmp_path, elements, points):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    out = tmp_path / "f.csv"
    _lock(out, dead.pid)
    rc, _, err = run_cli(["predict", "--model", elements, points, "--out", out])
    assert rc == 0, err
    assert f"taking over the stale lock of volcomp predict (pid {dead.pid}" in err
    assert out.is_file() and not file_lock_path(out).exists()


def test_a_run_leaves_only_its_file_and_a_refused_one_no_folder(tmp_path, elements, points):
    out = tmp_path / "new" / "sub" / "f.csv"
    rc, _, err = run_cli(["predict", "--model", elements, points, "--out", out])
    assert rc == 0, err
    assert sorted(p.name for p in out.parent.iterdir()) == ["f.csv", "f.meta.json"]   # the CSV and its sidecar
    bad = tmp_path / "other" / "g.csv"
    rc, _, err = run_cli(["predict", "--model", tmp_path / "missing.json", points, "--out", bad])
    assert rc == 2 and not (tmp_path / "other").exists(), err


def test_ctrl_c_removes_a_file_the_run_added_and_keeps_one_that_was_there(tmp_path):
    new, old = tmp_path / "new.csv", tmp_path / "old.csv"
    old.write_text("old\n")
    for target in (new, old):
        with pytest.raises(KeyboardInterrupt):
            with owned_output([(target, "file")], "predict"):
                target.write_text("written whole\n")
                raise KeyboardInterrupt
        assert not file_lock_path(target).exists()
    assert not new.exists() and old.read_text() == "written whole\n"
