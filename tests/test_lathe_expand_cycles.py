"""Fanuc lathe cycles of three kinds in one program with ``--expand-cycles``: a stepped shaft roughed by G71 and
finished by G70 (compensation/nc_contour.py), a thread by G92 and two modal passes (compensation/nc_thread.py), a
groove series by G75 (compensation/nc_groove.py). Each kind is written by its own expansion step, each step reading
the text again: what an earlier step decided (the roughing contour written as programmed, the cycle notes) must
survive the later ones. Program written here from the manuals' formats, not copied.

Checked independently of the expanders, on ``lathe-xzc`` with a seeded truth that is also the model: the lines that
are not a G70, G92 or G75 line are the source's byte for byte (the G71 and its contour written as programmed); every
point of the moves the control makes, rebuilt here from the manuals' rules (the G70's contour points, each G92
pass's start and thread end, the G75's pecks, returns and shifts by :func:`test_lathe_grooving.hand_moves`), is
reached, in order, by a written move whose TRUE tool tip (mean over one turn) lies within :data:`TOL_POINT_UM`; the
summary has the note of every cycle, in source-line order."""
import json
from types import SimpleNamespace

import numpy as np
import pytest
from test_lathe_grooving import hand_moves

from benchmarks.suite.gcode_checks import lathe_points_reached
from compensation.app.cli import main
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine

LATHE = "lathe-xzc"
SEED = 101
SCALE_UM, N_STATIONS = 10.0, 11
"""The truth: ChainElementSet.random(lathe, SEED, 10 um/urad, 11 stations), the lathe benchmark's truths; also the
model (``--method exact``): what is left is the solver's residual (~1e-4 um)."""
TOL_POINT_UM = 1.0
"""A programmed point is reached when the true tip is this close (the project's position tolerance)."""
PART_Z_MM = 200.0
"""The G54 work offset's Z (the part's face 200 mm along the bed, inside Z's stroke)."""

PROGRAM = """%
O0300 (SHAFT, THREAD, GROOVE)
G21 G18 G40 G99
T0101
G96 S180 M03
G00 X110. Z3.
G71 U1. R0.5
G71 P100 Q200 U0.4 W0.1 F0.25
N100 G00 X20.
G01 Z-30. F0.15
X40.
Z-60.
X60.
Z-80.
N200 X80.
G70 P100 Q200
G00 X150. Z50.
T0202
G97 S800
G00 X24. Z5.
G92 X19.4 Z-25. F1.5
X18.8
X18.4
G00 X150. Z50.
T0303
G96 S120
G00 X64. Z-62.
G75 R0.5
G75 X52. Z-67. P2000 Q2500 F0.08
G00 X150. Z50.
M05
M30
%
"""
"""A stepped shaft (the lathe benchmark's STEPS: two-block G71 type I, G70), an M20x1.5 thread on its X20 cylinder
by G92 and two modal passes, a 5 mm wide groove series on its X60 cylinder down to X52 (pecks of 2 mm returned
0.5 mm, columns 2.5 mm apart)."""
SRC = PROGRAM.splitlines()
G70_AT = SRC.index("G70 P100 Q200")
G92_AT = SRC.index("G92 X19.4 Z-25. F1.5")
G75_AT = SRC.index("G75 X52. Z-67. P2000 Q2500 F0.08")
CYCLE_LINES = {G70_AT: 1, G92_AT: 3, G75_AT: 1}
"""0-based source line of each cycle and how many lines it spans (the G92 with its two modal passes)."""

CONTOUR = [(10.0, -30.0), (20.0, -30.0), (20.0, -60.0), (30.0, -60.0), (30.0, -80.0), (40.0, -80.0)]
"""The G70's feed points (X radius, Z mm): the contour N100-N200 after its rapid."""
THREAD = [p for x in (19.4, 18.8, 18.4) for p in ((x / 2, 5.0), (x / 2, -25.0))]
"""Each G92 pass's start (after the rapid along X) and its thread's end (Fanuc 0i-TF, G92 operations 1-2)."""
GROOVE = [(x, z) for _, x, z in hand_moves("G75", (32.0, -62.0), (26.0, -67.0), 2.0, 2.5, 0.5)]
"""The G75's moves, rebuilt from the manual's rule (tests/test_lathe_grooving.py)."""


def _compensate(tmp_path):
    truth = tmp_path / "truth.json"
    ChainElementSet.random(load_machine(LATHE), SEED, SCALE_UM, N_STATIONS).save(truth)
    (tmp_path / "off.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{PART_Z_MM}\n")
    (tmp_path / "tools.csv").write_text("tool,length_mm,radius_mm\n1,0,0.8\n2,0,0.2\n3,0,0.2\n")
    src = tmp_path / "p.nc"
    src.write_text(PROGRAM)
    rc = main(["compensate", str(src), "--machine", LATHE, "--model", str(truth), "--truth", str(truth), "--method",
               "exact", "--dialect", "fanuc", "--lathe-x", "diameter", "--out", str(tmp_path / "out"),
               "--work-offsets", str(tmp_path / "off.csv"), "--tool-table", str(tmp_path / "tools.csv"),
               "--expand-cycles"])
    return rc, tmp_path / "out" / "p.nc", truth


def _kept_in_order(out):
    """The source's lines besides the cycles' found in ``out``, each run between two cycles contiguous and in order;
    returns the output line ranges the cycles were written as."""
    runs, at = [], 0
    for i in sorted(CYCLE_LINES) + [len(SRC)]:
        runs.append(SRC[at:i])
        at = i + CYCLE_LINES.get(i, 0)
    spans, k = [], 0
    for run in runs:
        j = next((j for j in range(k, len(out) - len(run) + 1) if out[j:j + len(run)] == run), None)
        assert j is not None, f"source lines {run[:2]}... not written as programmed"
        spans.append((k, j))
        k = j + len(run)
    assert k == len(out)
    return spans[1:]


def test_g70_g92_g75_expanded_together(tmp_path):
    rc, written, truth = _compensate(tmp_path)
    assert rc == 0
    out = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]
    assert out[:G70_AT] == SRC[:G70_AT]  # G71 and its contour written as programmed (uncompensated)
    spans = _kept_in_order(out)
    assert [b > a for a, b in spans] == [True, True, True]  # each cycle written as moves
    bare = tmp_path / "bare.nc"
    bare.write_text("\n".join(out) + "\n")
    lathe = load_machine(LATHE)
    moves = parse_lathe_program(bare, lathe, "keep", None, "fanuc", "diameter")[0].moves
    field = ChainField(lathe, ChainElementSet.load(truth, lathe))
    for (a, b), points in zip(spans, (CONTOUR, THREAD, GROOVE)):
        expected = [SimpleNamespace(end=np.array([x, z, 0.0]), index=k) for k, (x, z) in enumerate(points)]
        errs, missed = lathe_points_reached(field, lathe, expected, [m for m in moves if a <= m.index < b],
                                            (0.0, PART_Z_MM), TOL_POINT_UM)
        assert missed is None, f"point {missed} of the cycle written at lines {a + 1}-{b} reached by no written move"
        assert len(errs) == len(points) and max(errs) <= TOL_POINT_UM
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    notes = [n for n in summary["lathe_cycles"] if ": G32 F1.5 written as " not in n]  # the cycles' (then the leads')
    heads = [n.split(": ")[0] for n in notes]  # the source line and the written (flat) program's: the first of its own
    codes = [n.split(": ")[1].split(" (")[0].split(" expanded")[0] for n in notes]
    g71 = SRC.index("G71 P100 Q200 U0.4 W0.1 F0.25") + 1
    # the flat program's lines (before the compensated moves are split): the G70 written as its contour's 7 lines and
    # a G0 (7 lines more), each G92 pass as G0 X, G32, G0 X, G0 Z (3 more each)
    g70 = SRC.index("N200 X80.") - SRC.index("N100 G00 X20.") + 1
    assert heads == [f"line {g71} (expanded line {g71})", f"line {G70_AT + 1} (expanded line {G70_AT + 1})",
                     *(f"line {G92_AT + 1 + k} (expanded line {G92_AT + 1 + g70 + 4 * k})" for k in range(3)),
                     f"line {G75_AT + 1} (expanded line {G75_AT + 1 + g70 + 3 * 3})"]
    assert codes == ["G71 P100 Q200", "G70 P100 Q200", "G92 pass", "G92 pass", "G92 pass", "G75"]
    assert "uncompensated" in notes[0] and "roughing accuracy is not the part's" in notes[0]
    assert len(summary["lathe_cycles"]) == len(notes) + 3  # one lead line per G92 pass's thread
    assert summary["true"]["max_um"] <= TOL_POINT_UM < summary["true_uncompensated"]["max_um"]


CALLED = PROGRAM.replace("G00 X110. Z3.\n", "M98 P2000\n") + "O2000\nG00 X120. Z10.\nG00 X110. Z3.\nM99\n"
"""PROGRAM with its approach in a subprogram (Fanuc M98 of an O block after the end): the flat program the reader
expands holds the call's lines, so its line numbers are not the source's after the call."""


@pytest.mark.parametrize("old,new,where", [
    ("G70 P100 Q200", "G70 P100 Q200 F0.1", f"line {G70_AT + 1}, column 15: 'F0.1' on a G70 line"),
    ("G75 R0.5\n", "", f"line {G75_AT}, column 1: 'G75': the return after each peck e is the control's parameter"),
], ids=["G70", "G75"])
def test_a_refused_expansion_names_the_source_line_after_a_call(tmp_path, old, new, where):
    """A cycle refused while written as moves is named at its source line, once re-addressed from the flat line."""
    p = tmp_path / "p.nc"
    p.write_text(CALLED.replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        parse_lathe_program(p, load_machine(LATHE), "keep", None, "fanuc", "diameter", cycles="expand")
    assert f"{p}: {where}" in str(exc.value)


@pytest.mark.parametrize("code", ["G92", "G75"])
def test_a_cycle_refused_kept_names_the_source_line_after_a_call(tmp_path, code):
    """Kept (no --expand-cycles), a G92 pass and a G75 of several columns are refused on the reader's flat lines and
    named once at their source line (the call's lines before them in the flat program); for the G75 the G92 and its
    passes left out (the G92 is refused first)."""
    text = CALLED if code == "G92" else "".join(ln for i, ln in enumerate(CALLED.splitlines(True))
                                                if not G92_AT <= i < G92_AT + CYCLE_LINES[G92_AT])
    p = tmp_path / "p.nc"
    p.write_text(text)
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith(code + " X"))
    with pytest.raises(InputError) as exc:
        parse_lathe_program(p, load_machine(LATHE), "keep", None, "fanuc", "diameter")
    assert f"{p}: line {line}, column 1: '{code}'" in str(exc.value)
