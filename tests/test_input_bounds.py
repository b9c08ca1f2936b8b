"""Bounded work, command by command: every command that reads a user table refuses one past its kind's bound
(errormap/input_bounds.py) in one line naming the file, the rows and the bound, before the table is read whole
(the reader's whole-file read is watched) and before any work. Each kind's bound is lowered for the test
(SMALL_BOUND rows) so that a small synthetic file is over it; one kind is also checked at its real bound."""
from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import time

import numpy as np
import pytest

import errormap.io as eio
from compensation.app.cli import MAX_ERROR_CHARS, main
from errormap.input_bounds import BOUNDS
from errormap.machine import load_machine

SMALL_BOUND = 20
"""Rows each kind takes in these tests; the synthetic inputs have OVER rows."""
OVER = 60
REFUSAL_WALL_S = 5.0
"""The refusal of a file past its bound arrives within this (its lines are counted, nothing is parsed; the rest is
the command's imports, about a second on the loaded test machine)."""


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A grinder and a mill simulated (their element sets are the models), and a UR5 model.json (the plain
    LSQ fit of 40 simulated poses: what register needs before it reads the session's poses)."""
    from compensation.fields import ARM_FORMAT as MODEL_FORMAT
    from errormap.arm_calibration import fit_plain_lsq
    from errormap.arm_simulate import draw_truth, measure, random_joints
    d = tmp_path_factory.mktemp("bounds")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["simulate", "--seed", "3", "--checks", "30", "--out", str(d / "g")]) == 0
        assert main(["simulate", "--machine", "mill-xyz", "--seed", "3", "--checks", "30", "--out", str(d / "m")]) == 0
        (d / "p.csv").write_text("x_mm,z_mm,a_deg\n10,20,30\n")     # the commands' imports, once, outside the timing
        assert main(["predict", str(d / "p.csv"), "--model", str(d / "g" / "truth_elements.json"), "--out",
                     str(d / "p_out.csv")]) == 0
    ur5 = load_machine("ur5")
    lo, hi = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0]), np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
    geo = fit_plain_lsq(ur5, measure(ur5, draw_truth(ur5, 7), random_joints(lo, hi, 40, [7, 0]), 0.02, [7, 1]))
    (d / "arm.json").write_text(json.dumps({"format": MODEL_FORMAT, "machine": {"name": ur5.name,
                                                                                "joints": ur5.joint_columns},
                                            "kept_stage": "plain geometric LSQ", "geometric": geo.to_dict(),
                                            "plain_geometric": geo.to_dict(),
                                            "learned": None}))
    return d


def _synthetic(path, n_cols=6):
    """OVER data rows of plain numbers under a header of ``n_cols`` names: only its line count matters here."""
    path.write_text(",".join(f"c{i}" for i in range(n_cols)) + "\n" + ("1," * (n_cols - 1) + "1\n") * OVER)
    return path


# (kind, argv with {f} the oversize file, {d} the fixture's folder, {o} an output folder)
CASES = [
    ("points", ["predict", "{f}", "--model", "{d}/g/truth_elements.json", "--out", "{o}/p.csv"]),
    ("points", ["predict", "{f}", "--machine", "ur5", "--model", "{d}/arm.json", "--out", "{o}/p.csv"]),
    ("featurepoints", ["train", "{f}", "--out", "{o}/t"]),
    ("checks", ["diagnose", "{f}", "--model", "{d}/g/truth_elements.json", "--out", "{o}/dg"]),
    ("checks", ["diagnose", "{f}", "--machine", "mill-xyz", "--model", "{d}/m/truth_elements.json", "--out", "{o}/dm"]),
    ("thermal log", ["diagnose", "--drift", "{f}", "--out", "{o}/dd"]),
    ("sweeps", ["identify", "{f}", "--out", "{o}/E.json"]),
    ("sweeps", ["identify", "{f}", "--machine", "mill-xyz", "--out", "{o}/E.json"]),
    ("poses", ["calibrate", "{f}", "--machine", "ur5", "--out", "{o}/c"]),
    ("poses", ["calibrate", "{f}", "--machine", "hexapod", "--out", "{o}/c"]),
    ("poses", ["register", "{f}", "--machine", "ur5", "--model", "{d}/arm.json", "--out", "{o}/r"]),
    ("waypoints", ["interpolate", "{f}", "--machine", "hexapod", "--out", "{o}/i.csv"]),
]


def _run(argv):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        t0 = time.perf_counter()
        rc = main([str(a) for a in argv])
    return rc, err.getvalue(), time.perf_counter() - t0


def test_every_kind_a_command_reads_has_a_case():
    assert {k for k, _ in CASES} == set(BOUNDS)


@pytest.mark.parametrize("kind,argv", CASES, ids=[f"{a[0]}-{a[-3] if a[-3] != '{f}' else a[1]}-{k}"
                                                  for k, a in CASES])
def test_an_input_past_its_bound_is_refused_unread_in_one_line(kind, argv, made, tmp_path, monkeypatch):
    b = BOUNDS[kind]
    monkeypatch.setitem(BOUNDS, kind, dataclasses.replace(b, max_rows=SMALL_BOUND))
    f = _synthetic(tmp_path / "big.csv")
    real_read = eio._read_all

    def watched(path):
        assert str(path) != str(f), f"{f} was read whole before its bound was checked"
        return real_read(path)
    monkeypatch.setattr(eio, "_read_all", watched)
    argv = [a.format(f=f, d=made, o=tmp_path / "out") for a in argv]
    rc, err, wall = _run(argv)
    lines = [ln for ln in err.strip().splitlines() if ": error: " in ln]     # progress lines aside
    assert rc == 2 and len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS, (argv, err)
    assert str(f) in lines[0] and f"about {OVER:,} rows of {b.what}" in lines[0], lines[0]
    assert f"limit of {SMALL_BOUND:,} for {b.commands}" in lines[0], lines[0]
    assert not (tmp_path / "out").exists() and wall < REFUSAL_WALL_S


def test_a_check_file_one_row_past_the_real_bound_is_refused_at_once(made, tmp_path):
    """The real bound of check files: a file one row past it is refused unread, with the estimate."""
    b = BOUNDS["checks"]
    n = b.max_rows + 1
    f = tmp_path / "checks.csv"
    f.write_text("x_mm,z_mm,a_deg,dx_um,dy_um,dz_um\n" + "1,2,3,4,5,6\n" * n)
    rc, err, wall = _run(["diagnose", f, "--model", made / "g" / "truth_elements.json", "--out", tmp_path / "o"])
    assert rc == 2 and f"about {n:,} rows of check measurements exceed the limit of {b.max_rows:,}" in err, err
    assert b.estimate(n) in err
    assert wall < REFUSAL_WALL_S


def test_a_table_at_its_bound_is_read(tmp_path, monkeypatch):
    """At the bound (not past it) the table reads: the bound is an upper limit, not an off-by-one."""
    b = BOUNDS["checks"]
    monkeypatch.setitem(BOUNDS, "checks", dataclasses.replace(b, max_rows=SMALL_BOUND))
    f = tmp_path / "t.csv"
    f.write_text("a,b\n" + "1,2\n" * SMALL_BOUND)
    assert len(eio.read_table(f, "checks")) == SMALL_BOUND
    f.write_text("a,b\n" + "1,2\n" * (SMALL_BOUND + 1))
    with pytest.raises(eio.InputError, match=f"about {SMALL_BOUND + 1} rows"):
        eio.read_table(f, "checks")


BOUND_CPU_S = 600.0
"""A command at its sweep bound stays within minutes of CPU (errormap/input_bounds.py's rule for every bound)."""
BOUND_BYTES = 8e9
"""... and a few GB of peak memory (the diagnose bound's 4.3 GB measured; 8 GB the most any bound may estimate)."""


def test_the_sweep_bound_is_what_its_measured_cost_allows():
    """The sweep bound's own estimate at the bound (scaled from the measured run it names) stays within
    BOUND_CPU_S and BOUND_BYTES, and the measured run lies at most a factor 3 below the bound (a short
    extrapolation)."""
    b = BOUNDS["sweeps"]
    cpu_s, peak_bytes = b.cost(b.max_rows)
    assert cpu_s <= BOUND_CPU_S and peak_bytes <= BOUND_BYTES
    assert b.ref_rows <= b.max_rows <= 3 * b.ref_rows


def test_a_sweep_file_one_row_past_the_real_bound_is_refused_at_once(tmp_path):
    """The real bound of sweep files: one row past it is refused unread, with the estimate."""
    b = BOUNDS["sweeps"]
    n = b.max_rows + 1
    f = tmp_path / "sweeps.csv"
    f.write_text("axis,station,command,target,x_mm,y_mm,z_mm\n" + "X,0,0,1,1,2,3\n" * n)
    rc, err, wall = _run(["identify", f, "--out", tmp_path / "E.json"])
    assert rc == 2 and f"about {n:,} rows of sweep rows exceed the limit of {b.max_rows:,}" in err, err
    assert b.estimate(n) in err
    assert wall < REFUSAL_WALL_S
