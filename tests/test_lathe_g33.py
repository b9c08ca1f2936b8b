"""LinuxCNC spindle-synchronised motion on a lathe (compensation/nc_thread.py): ``G33`` split in consecutive pieces,
each with its own K, ``G33.1`` one move with one K. Programs written here from the LinuxCNC G-code reference ("G33
Spindle Synchronized Motion": ``G33 X- Z- K-``, K the distance per revolution along the drive line; "G33.1 Rigid
Tapping"; the G33 example's passes: rapid to the pass's X, G33 along Z, rapid out in X, back in Z), not copied.

Why split: LinuxCNC waits for the spindle index at the start of every *chain* of synchronised moves (motion(9),
``spindle-at-speed``: "before the start of every chain of spindle-synchronized moves"); consecutive G33 lines are one
chain, so pieces keep the thread's phase, as a Fanuc G32 sequence does. A G33.1 (a tap and its return) is one move
(tests/test_linuxcnc_words.py, on a mill: on a lathe's axis, X = 0, the turning solve does not converge).

Checked independently of the compensator, on ``lathe-xzc`` with a seeded truth that is also the model: every
programmed point (each pass's start, each G33 end) reached by a written move whose TRUE tip (mean over one turn) is
within :data:`TOL_POINT_UM`; every written G33 piece's TRUE lead (its written K' × true travel / commanded travel along
the drive line, benchmarks.suite.lathe.true_leads) equals the programmed K within
:data:`compensation.nc_thread.LEAD_TOL_REL`; every pass starts at one TRUE Z (its phase); the lines that are not moves
byte for byte."""
import json

import numpy as np
import pytest

from benchmarks.suite.gcode_checks import lathe_points_reached
from benchmarks.suite.lathe import true_leads
from compensation.app.cli import main
from compensation.nc_thread import LEAD_TOL_REL
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine

LATHE = "lathe-xzc"
SEED = 7
SCALE_UM, N_STATIONS = 10.0, 11
"""The truth: ChainElementSet.random(lathe, SEED, 10 um/urad, 11 stations), as tests/test_lathe_threading.py."""
TOL_POINT_UM = 1.0
"""A programmed point is reached when the true tip is this close (the project's position tolerance)."""
PART_Z_MM = 200.0
"""The G54 work offset's Z."""
K_MM = 1.5

G33_PASSES = ("(M30x1.5 in three passes, LinuxCNC G33)\nG21 G18 G90 G7\nG54\nS800 M3\nG0 X40 Z5\nX29.4\n"
              "G33 Z-30 K1.5\nG0 X40\nZ5\nX28.8\nG33 Z-30 K1.5\nG0 X40\nZ5\nX28.4\nG33 Z-10 K1.5\nG33 Z-30 K1.5\n"
              "G0 X40\nZ5\nG1 X38 F100\nM5\nM2\n")
"""Three passes (diameter mode G7), the third two consecutive G33 blocks (one chain), then a feed move."""


def _compensate(tmp_path, text, extra=(), name="p.ngc"):
    truth = tmp_path / "truth.json"
    ChainElementSet.random(load_machine(LATHE), SEED, SCALE_UM, N_STATIONS).save(truth)
    (tmp_path / "off.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{PART_Z_MM}\n")
    src = tmp_path / name
    src.write_text(text)
    rc = main(["compensate", str(src), "--machine", LATHE, "--model", str(truth), "--truth", str(truth), "--method",
               "exact", "--dialect", "linuxcnc", "--out", str(tmp_path / "out"), "--work-offsets",
               str(tmp_path / "off.csv"), *extra])
    return rc, src, tmp_path / "out" / name, truth


def _read(path):
    return parse_lathe_program(path, load_machine(LATHE), "keep", None, "linuxcnc")[0]


def _field(truth):
    lathe = load_machine(LATHE)
    return lathe, ChainField(lathe, ChainElementSet.load(truth, lathe))


def checked(truth, p_src, p_out, lead_mm):
    """``(programmed compensated moves, TRUE lead error per written piece, TRUE start Z per pass)`` of a written
    thread ``p_out`` against its program ``p_src`` (module docstring), asserting every programmed point reached within
    :data:`TOL_POINT_UM` and every piece's TRUE lead ``lead_mm`` within LEAD_TOL_REL."""
    lathe, field = _field(truth)
    m_src = [m for m in p_src.moves if m.compensate]
    errs, missed = lathe_points_reached(field, lathe, m_src, [m for m in p_out.moves if m.compensate],
                                        (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None and len(errs) == len(m_src) and max(errs) <= TOL_POINT_UM
    lead_err, starts = true_leads(field, lathe, p_out.moves, (0.0, PART_Z_MM), lead_mm)
    assert np.abs(lead_err).max() <= LEAD_TOL_REL
    return m_src, lead_err, starts


def test_g33_passes_split_each_piece_true_lead_k_and_passes_in_phase(tmp_path):
    rc, src, written, truth = _compensate(tmp_path, G33_PASSES)
    assert rc == 0
    p_src, p_out = _read(src), _read(written)
    bare = [ln for ln, c in zip(p_out.lines, p_out.classes) if c != "move" and not ln.startswith("(volcomp:")]
    assert [ln for ln, c in zip(p_src.lines, p_src.classes) if c != "move"] == bare
    assert not any("C" in ln.split("(")[0].upper() for ln in p_out.lines if not ln.startswith("("))
    m_src, lead_err, starts = checked(truth, p_src, p_out, K_MM)
    assert sum(m.lead is not None for m in m_src) == 4 and sum(m.kind == "rapid" for m in m_src) == 3  # pass starts
    assert len(lead_err) > 4  # split in pieces (the error is not linear along 35 mm)
    assert len(starts) == 3 and np.ptp(starts) * 1e3 <= TOL_POINT_UM  # one TRUE start Z: the passes in phase
    lathe, field = _field(truth)
    unc_err, unc_starts = true_leads(field, lathe, p_src.moves, (0.0, PART_Z_MM), K_MM)
    assert np.abs(unc_err).max() > 10 * LEAD_TOL_REL  # the truth bends the lead: the check can fail
    out = written.read_text().splitlines()
    pieces = [ln for ln in out if ln.startswith("G33") or (ln.startswith(("X", "Z")) and " K" in ln)]
    assert len(pieces) == len(lead_err) and all(" K" in ln and "F" not in ln for ln in pieces)
    assert next(ln for ln in out if ln.startswith("G1 ")).endswith(" F100")  # a feed keeps its F
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    notes = summary["lathe_cycles"]
    assert sum("thread's start" in c for c in notes) == 3
    leads = [c for c in notes if ": G33 K1.5 written as " in c]
    assert len(leads) == 4 and sum(int(c.split("written as ")[1].split(" ")[0]) for c in leads) == len(lead_err)

