"""Fanuc/Haas lathe threading (compensation/nc_thread.py): G32 compensated in pieces each with its own lead, G92
written as its passes' moves with ``--expand-cycles``, G76 refused. Programs written here from the manuals' formats
(Fanuc 0i-TF ``G32 X Z F`` and ``G92 X Z F`` with modal X passes; Haas lathe manual G32), not copied.

Checked independently of the compensator, on ``lathe-xzc`` with a seeded truth that is also the model: the lines that
are not moves are the source's byte for byte; every programmed point (each pass's start, each G32 end) is reached by
a written move whose TRUE tip (mean over one turn) is within :data:`TOL_POINT_UM`; every written G32 piece's TRUE
lead (its written F' × true travel / commanded travel along the lead axis) equals the programmed F within
:data:`compensation.nc_thread.LEAD_TOL_REL`; every pass of a thread starts at one TRUE Z (its phase); no C word."""
import json

import numpy as np
import pytest

from benchmarks.suite.gcode_checks import lathe_points_reached
from benchmarks.suite.lathe import THREAD, THREAD_LEAD_MM, true_leads
from compensation.app.cli import main
from compensation.nc_thread import LEAD_TOL_REL
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine

LATHE = "lathe-xzc"
SEED = 7
SCALE_UM, N_STATIONS = 10.0, 11
"""The truth: ChainElementSet.random(lathe, SEED, 10 um/urad, 11 stations), the benchmarks' lathe truths."""
TOL_POINT_UM = 1.0
"""A programmed point is reached when the true tip is this close (the project's position tolerance)."""
PART_Z_MM = 200.0
"""The G54 work offset's Z."""

G32_PASSES = THREAD
"""An M30x1.5 thread in three G32 passes (the second's lead modal, the third two consecutive G32 blocks), then a
feed move with its own F and one without (the lathe benchmark's program: benchmarks/suite/lathe.py THREAD)."""

G92_PASSES = G32_PASSES.split("G00 X40. Z5.\n")[0] + "G00 X40. Z5.\nG92 X29.4 Z-30. F1.5\nX28.8\nX28.4\n" \
    "G00 X100. Z50.\nM05\nM30\n%\n"
"""The same thread by a G92 and two modal passes (Fanuc 0i-TF: 'X' alone repeats the cycle, Z and F kept)."""
G92_MOVES = "G21 G18 G99\nG00 X40. Z5.\n" + "".join(f"G00 X{x}\nG32 Z-30. F1.5\nG00 X40.\nG00 Z5.\n"
                                                       for x in ("29.4", "28.8", "28.4"))
"""The moves the control makes for G92_PASSES (Fanuc 0i-TF "thread cutting cycle": rapid X, thread Z, rapid X back,
rapid Z back), written here as the reference whose points the expansion must reach."""


def _compensate(tmp_path, text, dialect="fanuc", extra=(), name="p.nc"):
    truth = tmp_path / "truth.json"
    ChainElementSet.random(load_machine(LATHE), SEED, SCALE_UM, N_STATIONS).save(truth)
    (tmp_path / "off.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{PART_Z_MM}\n")
    (tmp_path / "tools.csv").write_text("tool,length_mm,radius_mm\n1,0,0.8\n")
    src = tmp_path / name
    src.write_text(text)
    rc = main(["compensate", str(src), "--machine", LATHE, "--model", str(truth), "--truth", str(truth), "--method",
               "exact", "--dialect", dialect, "--lathe-x", "diameter", "--out", str(tmp_path / "out"),
               "--work-offsets", str(tmp_path / "off.csv"), "--tool-table", str(tmp_path / "tools.csv"), *extra])
    return rc, src, tmp_path / "out" / name, truth


def _read(path, dialect="fanuc"):
    return parse_lathe_program(path, load_machine(LATHE), "keep", None, dialect, "diameter")[0]


def _true_leads(written, truth, dialect="fanuc"):
    """``(relative TRUE lead errors, TRUE start Z of each pass mm)`` of every written G32 piece (the benchmark's
    check, benchmarks.suite.lathe.true_leads: written F' × true travel / commanded travel along the lead axis)."""
    lathe = load_machine(LATHE)
    field = ChainField(lathe, ChainElementSet.load(truth, lathe))
    return true_leads(field, lathe, _read(written, dialect).moves, (0.0, PART_Z_MM), THREAD_LEAD_MM)


def _non_moves(prog):
    return [ln for ln, c in zip(prog.lines, prog.classes) if c != "move"]


@pytest.mark.parametrize("dialect", ["fanuc", "haas"])
def test_g32_passes_exact_position_and_lead(tmp_path, dialect):
    rc, src, written, truth = _compensate(tmp_path, G32_PASSES, dialect)
    assert rc == 0
    p_src, p_out = _read(src, dialect), _read(written, dialect)
    bare = [ln for ln in p_out.lines if not ln.startswith("(volcomp:")]
    assert _non_moves(p_src) == [ln for ln, c in zip(p_out.lines, p_out.classes) if c != "move" and ln in bare]
    assert not any("C" in ln.split("(")[0].upper() for ln in bare)  # turning: the spindle is not an axis
    lathe = load_machine(LATHE)
    field = ChainField(lathe, ChainElementSet.load(truth, lathe))
    m_src = [m for m in p_src.moves if m.compensate]
    errs, missed = lathe_points_reached(field, lathe, m_src, [m for m in p_out.moves if m.compensate],
                                        (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None and max(errs) <= TOL_POINT_UM
    assert sum(m.lead is not None for m in m_src) == 4 and len(errs) == len(m_src)
    lead_err, starts = _true_leads(written, truth, dialect)
    assert len(lead_err) > 4  # split in pieces (the error is not linear along 35 mm)
    assert np.abs(lead_err).max() <= LEAD_TOL_REL
    assert len(starts) == 3 and np.ptp(starts) * 1e3 <= TOL_POINT_UM  # every pass starts at one true Z: one phase
    out = written.read_text().splitlines()
    k = next(i for i, ln in enumerate(out) if ln.startswith("G01 "))
    assert out[k].endswith(" F0.2") and "F" not in out[k + 1]  # its own F kept; the next: the modal F0.2 of it
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    assert sum("thread's start" in c for c in summary["lathe_cycles"]) == 3
    leads = [c for c in summary["lathe_cycles"] if ": G32 F1.5 written as " in c]  # one per G32 block, its pieces
    assert len(leads) == 4 and sum(int(c.split("written as ")[1].split(" ")[0]) for c in leads) == len(lead_err)


@pytest.mark.parametrize("new,restored", [("G01 X38.\n", True), ("F0.3\nG01 X38.\n", False)])
def test_g32_feed_after_thread_gets_programmed_f(tmp_path, new, restored):
    """After a thread the modal F is the last piece's F': a feed move without F gets the programmed F back, unless a
    line between gave an F (the control's modal F is that one)."""
    rc, _, written, _ = _compensate(tmp_path, G32_PASSES.replace("G01 X38. F0.2\n", new))
    assert rc == 0
    line = next(ln for ln in written.read_text().splitlines() if ln.startswith("G01 "))
    assert line.endswith(" F1.5") == restored and line.count("F") == restored


def test_g92_expanded_exact_and_refused_kept(tmp_path, capsys):
    rc, *_ = _compensate(tmp_path, G92_PASSES)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and "line 7, column 1: 'G92' (thread cutting cycle) kept as a cycle" in err
    assert "use --expand-cycles" in err
    rc, src, written, truth = _compensate(tmp_path, G92_PASSES, extra=("--expand-cycles", "--force"))
    assert rc == 0
    p_out = _read(written)
    src_lines = src.read_text().splitlines(keepends=True)  # its moves: the G00 lines and the G92 passes
    assert [ln for ln in src_lines if not ln.startswith(("G00", "G92", "X28"))] == \
        [ln for ln in _non_moves(p_out) if not ln.startswith("(volcomp:")]
    ref = tmp_path / "ref.nc"
    ref.write_text(G92_MOVES)
    lathe = load_machine(LATHE)
    field = ChainField(lathe, ChainElementSet.load(truth, lathe))
    ref_moves = _read(ref).moves  # the cut points: each G32 end and each pass's start (the rapids back are kept)
    m_ref = [m for m, nxt in zip(ref_moves, ref_moves[1:] + [ref_moves[-1]]) if nxt.lead is not None or m.lead]
    errs, missed = lathe_points_reached(field, lathe, m_ref, [m for m in p_out.moves if m.compensate],
                                        (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None and max(errs) <= TOL_POINT_UM and len(errs) == len(m_ref) == 6
    lead_err, starts = _true_leads(written, truth)
    assert np.abs(lead_err).max() <= LEAD_TOL_REL and len(starts) == 3 and np.ptp(starts) * 1e3 <= TOL_POINT_UM


@pytest.mark.parametrize("old,new,dialect,where", [
    ("G32 Z-30. F1.5", "G32 Z-30.", "fanuc", "line 8, column 1: 'G32' without F (the lead)"),
    ("G32 Z-30. F1.5", "G32 Z-30. F1.5 Q90000", "fanuc", "line 8, column 16: 'Q90000' on a G32 line"),
    ("G32 Z-30. F1.5", "G76 P020060 Q50 R0.02\nG76 X28. Z-30. P920 Q400 F1.5", "fanuc",
     "line 8, column 1: 'G76' on a fanuc lathe: multiple threading cycle: its passes"),
    ("X29.4\nG32 Z-30. F1.5", "G92 X29.4 Z-30. F1.5", "haas", "line 7, column 1: 'G92' on a haas lathe"),
    ("X29.4\nG32 Z-30. F1.5", "G92 X29.4 Z-30. R-1. F1.5", "fanuc", "line 7, column 17: 'R-1.' on a G92"),
    ("M03\nG00 X40. Z5.", "\nG00 X40. Z5. C0.", "fanuc", "line 8: 'G32' while the spindle is stopped"),
])
def test_threading_refusals_name_line_column_word(tmp_path, capsys, old, new, dialect, where):
    rc, *_ = _compensate(tmp_path, G32_PASSES.replace(old, new, 1), dialect, extra=("--expand-cycles",))
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and where in err and "Traceback" not in err
