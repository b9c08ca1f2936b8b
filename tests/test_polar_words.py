"""LinuxCNC's polar coordinates (compensation/nc_polar.py) read exactly or refused by name.

LinuxCNC G-code reference, "Polar Coordinates": ``@`` the distance, ``^`` the angle of the XY point of a move,
from the XY zero of the current coordinate system, the angle from +X counter-clockwise; "G1 @1^90 is the same
as G1 Y1"; in relative mode (G91) "the distance and angle is also from the XY zero position but it is
cumulative" (the manual's spiral: ``G91 @.5 ^90`` repeated adds 0.5 to the distance each time; its square:
``G91 ^90`` repeated keeps the distance); "it is an error if an incremental move is started at the origin, or
a mix of polar and X or Y words are used". The programs here are written from that wording; the expected
points are worked out by hand below (not by the reader). Accepted programs are compensated on mill-xyz
against a simulated truth and checked: every other line byte-identical, every programmed point reached by
the TRUE machine within 1 μm."""
import math

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups

WORK_MM = np.array([300.0, 200.0, -300.0])
"""G54 of the tests (mill-xyz)."""
TOL_EXPANDED_MM = 1e-6
"""The flat program's numbers carry 10 decimals (program units): 1e-10 mm, 2.5e-9 mm under G20."""
SQRT_HALF = math.sqrt(0.5)

SPIRAL = "G21 G90 G17\nG0 X0 Y0 Z10\nF100 G1 @.5 ^90\nG91 @.5 ^90\n@.5 ^90\n@.5 ^90\n@.5 ^90\nG90 G0 X0 Y0 M2\n"
SPIRAL_POINTS = {3: (0.0, 0.5), 4: (-1.0, 0.0), 5: (0.0, -1.5), 6: (2.0, 0.0), 7: (0.0, 2.5)}
"""The manual's spiral: distance 0.5, 1, 1.5, 2, 2.5 at 90°, 180°, 270°, 360°, 450°."""
SQUARE = "G21 G90 G17\nG0 X0 Y0 Z10\nF100 G1 @.5 ^90\nG91 ^90\n^90\n^90\n^90\nG90 G0 X0 Y0 M2\n"
SQUARE_POINTS = {3: (0.0, 0.5), 4: (-0.5, 0.0), 5: (0.0, -0.5), 6: (0.5, 0.0), 7: (0.0, 0.5)}
"""The manual's square: distance 0.5 at 90°, 180°, 270°, 360°, 450°."""
MIXED = ("G21 G90 G17\nG0 X10 Y0 Z5\nG1 @1^90 F200\nG1 @20\nG0 ^45\nG1 Z-2\nG20 G1 ^0\nG91 G1 @0.5\n"
         "G21 G90 G0 X30 Y40\nG1 @100 (same angle, 100 mm)\nM2\n")
MIXED_POINTS = {3: (0.0, 1.0, 5.0), 4: (0.0, 20.0, 5.0), 5: (20 * SQRT_HALF, 20 * SQRT_HALF, 5.0),
                6: (20 * SQRT_HALF, 20 * SQRT_HALF, -2.0), 7: (20.0, 0.0, -2.0), 8: (32.7, 0.0, -2.0),
                10: (60.0, 80.0, -2.0)}
"""By hand: '@1^90' is Y1; '@20' alone keeps the angle (90°); '^45' alone keeps the distance 20; under G20
'^0' keeps the distance (20 mm) at 0°; 'G91 @0.5' (inch) adds 12.7 mm along the current angle; '@100' from
(30, 40) keeps its angle: (60, 80)."""


def _read(text, tmp_path, dialect="linuxcnc", name="p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    return p, parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect)


@pytest.mark.parametrize("text, points", [(SPIRAL, SPIRAL_POINTS), (SQUARE, SQUARE_POINTS), (MIXED, MIXED_POINTS)])
def test_polar_points_follow_the_manual(tmp_path, text, points):
    _, prog = _read(text, tmp_path)
    ends = {m.index + 1: m.end for m in prog.moves if m.kind == "linear" or m.index + 1 in points}
    for line, want in points.items():
        assert np.abs(ends[line][:len(want)] - want).max() <= TOL_EXPANDED_MM, (line, ends[line], want)
    assert "@" not in prog.expanded.text and "^" not in prog.expanded.text


@pytest.mark.parametrize("text, line, col, words", [
    ("G21 G90\nG0 X1 Y1 Z1\nG5 @5 ^30 I1 J1 P1 Q1\nM2\n", 3, 4, ("'@'", "G5", "G0 G1 G2 G3")),
    ("G21 G90\nG0 X1 Y1 Z1\nG1 X2 @5\nM2\n", 3, 7, ("'@'", "with 'X'")),
    ("G21 G90\nG0 X0 Y0 Z1\nG1 @5 F100\nM2\n", 3, 4, ("'@'", "alone at the origin")),
    ("G21 G90\nG0 X0 Y0 Z1\nG91 G1 ^30 F100\nM2\n", 3, 8, ("'^'", "incremental (G91) at the origin")),
    ("G21 G90\nG0 X1 Y1 Z1\nG53 G0 @5 ^30\nM2\n", 3, 8, ("'@'", "G53")),
    ("G21 G90\nG0 X1 Y1 Z1\nG55 G1 @5 ^30 F100\nM2\n", 3, 8, ("'@'", "G55")),
    ("G21 G90\nG0 Z1\nG1 @5 F100\nM2\n", 3, 4, ("'@'", "X and Y are known")),
])
def test_what_linuxcnc_refuses_or_the_reader_does_not_follow_is_refused_by_name(tmp_path, text, line, col, words):
    with pytest.raises(InputError) as err:
        _read(text, tmp_path)
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line {line}, column {col}: ") and len(msg) - len(str(tmp_path)) < 300, msg
    assert all(w in msg for w in words), msg


def test_polar_words_on_another_dialect_are_refused(tmp_path):
    with pytest.raises(InputError, match=r"line 3, column 4: '@': a LinuxCNC polar coordinate on a fanuc program"):
        _read("G21 G90\nG0 X1 Y1 Z1\nG1 @5 ^30 F100\nM30\n", tmp_path, dialect="fanuc")


def test_a_polar_program_compensated_reaches_every_point(tmp_path):
    """The flat program (X Y written for @ ^) run as LinuxCNC runs it: machine = written + G54; the TRUE tool
    point at every programmed point (by hand, :data:`MIXED_POINTS`) within 1 μm; every other line as it was."""
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    (tmp_path / "offsets.csv").write_text("system,x_mm,y_mm,z_mm\nG54,%g,%g,%g\n" % tuple(WORK_MM))
    src, _ = _read(MIXED, tmp_path)
    assert main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(tmp_path / "out"), "--dialect", "linuxcnc",
                 "--work-offsets", str(tmp_path / "offsets.csv")]) == 0
    out = parse_program(tmp_path / "out" / src.name, axis_words=AxisWords.of(mill), fast=False, dialect="linuxcnc")
    head = sum(1 for ln in out.lines if ln.startswith("(volcomp:"))
    body = out.lines[head:]
    src_lines = MIXED.splitlines(keepends=True)
    groups = _groups(src_lines, body)  # a long move's added lines start with X
    for i, (a, g) in enumerate(zip(src_lines, groups), start=1):
        if "@" not in a and "^" not in a and i not in MIXED_POINTS:
            assert [body[k] for k in g] == [a], (i, a)  # byte-identical
    field = ChainField(mill, ChainElementSet.load(truth, mill))
    by_line = {m.index - head: m.end for m in out.moves}
    ends = {i: by_line[g[-1]] for i, g in enumerate(groups, start=1) if g[-1] in by_line}
    errs = []
    for line, want in MIXED_POINTS.items():
        if line in (5, 10):  # G0 rapids: kept as written
            continue
        q = ends[line] + WORK_MM
        tip = mill.nominal(q[None])[0] + field.predict(q[None])[0] * 1e-3
        errs.append(np.linalg.norm(tip - mill.nominal((np.array(want) + WORK_MM)[None])[0]) * 1e3)
    assert len(errs) == 5 and max(errs) <= TOL_POINT_UM, errs


def test_a_polar_arc_end_is_the_arc_to_the_same_x_y(tmp_path):
    """LinuxCNC takes an arc's end from the polar words as it does a line's (``find_ends``): 'G3 @10 ^90 R10' from
    (10, 0) is the quarter circle 'G3 X0 Y10 R10' (by hand: distance 10 at 90°); I J stay relative to the start."""
    _, polar = _read("G21 G90 G17\nG0 X10 Y0 Z0\nG3 @10 ^90 R10 F100\nG91 G2 ^-90 I0 J-10\nM2\n", tmp_path)
    _, plain = _read("G21 G90 G17\nG0 X10 Y0 Z0\nG3 X0 Y10 R10 F100\nG91 G2 X10 Y-10 I0 J-10\nM2\n", tmp_path,
                     name="q.ngc")
    arcs = [(m for m in p.moves if m.kind == "arc") for p in (polar, plain)]
    for a, b in zip(*arcs):
        assert np.abs(a.end - b.end).max() <= TOL_EXPANDED_MM and a.arc.keys() == b.arc.keys()
        assert all(np.abs(np.asarray(a.arc[k], float) - np.asarray(b.arc[k], float)).max() <= TOL_EXPANDED_MM
                   for k in a.arc if isinstance(a.arc[k], (int, float)))
