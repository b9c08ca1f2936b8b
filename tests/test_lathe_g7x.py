"""LinuxCNC's lathe cycles G70 (finishing) and G71/G72 (roughing) whose contour is the o-subroutine Q names
(compensation/nc_g7x.py, compensation/nc_g7x_path.py): read exactly, written with ``--expand-cycles`` as the moves
LinuxCNC's interpreter makes, each compensated point by point; refused kept. Programs written here from the LinuxCNC
G-code reference ("G70 Lathe finishing cycle": ``G70 Q- X- Z- D- E- P-``; "G71 G72 Lathe roughing cycles":
``G71 Q- X- Z- D- I- R-``), not copied.

The expected moves are computed here from the cycles' rules, for a turned step (a Z line at radius ``A`` from the
start's Z to ``ZF``, then a face up to the start's X), independently of the reader:

- G70: passes k = P … 1 at distance (k − 1)(D − E)/P + E from the contour (interp_g7x.cc's ``do_g70``): at distance
  δ the Z line lies at X = A + δ and the face at Z = ZF + δ, meeting there; each pass rapids to the start point, rapids
  to the offset contour's first point, then feeds along it (the contour's G0 lines too);
- G71: the contour offset by D; levels X = X0 − k·I (k = 0, 1, …) while above A + D, each a rapid to the level at the
  start's Z, a feed along Z to the offset face (Z = ZF + D), a rapid escape by R in X and Z, a rapid back along Z to
  the start's Z − R, a rapid down to the level; then a rapid to A + D, a feed along the offset Z line and up the face.

G72 is checked on a face (the same rules turned a quarter), G71.2 on a groove (only the pocket cut, at levels I
apart between its flanks). The compensated program is checked on ``lathe-xzc`` with a seeded truth that is also the model
(tests/test_lathe_g33.py's truth and part zero): every point of the expanded moves reached, in order, by a written
move whose TRUE tip (mean over one turn) lies within :data:`test_lathe_g33.TOL_POINT_UM`; the lines that are not
moves byte for byte. The arithmetic of compensation/nc_g7x_path.py was also compared, outside the test suite, with
LinuxCNC's own interp_g7x.cc compiled on its own (1,800 random contours of lines and arcs, every cycle: the same moves
within 3e-8 mm, the same refusals, and a refusal where the reference crashes)."""
import json

import numpy as np
import pytest
from test_lathe_g33 import LATHE, PART_Z_MM, TOL_POINT_UM, _compensate, _field

from benchmarks.suite.gcode_checks import lathe_points_reached
from compensation.turning import parse_lathe_program
from errormap.io import InputError
from errormap.machine import load_machine

TOL_WRITTEN_MM = 1e-6
"""An expanded move's end equals the reference's within this: the written words' rounding (7 decimals: 0.5e-7 mm)
with margin."""
X0, Z0, A, ZF = 20.0, 2.0, 10.0, -20.0
"""The start point (radius, Z mm), the step's radius and its face's Z."""
STEP = ("(turned step, LinuxCNC G71 and G70)\nG21 G18 G90 G8\nG54\nS800 M3\nF200\n"
        "O100 SUB\n  G0 X{a:g} (onto the contour)\n  G1 Z{zf:g} (along the step)\n  G1 X{x0:g}\nO100 ENDSUB\n"
        "G0 X{x0:g} Z{z0:g}\n{cycle}\nG0 X40 Z10\nM5\nM2\n")


def _program(cycle, x0=X0, a=A):
    return STEP.format(a=a, zf=ZF, x0=x0, z0=Z0, cycle=cycle)


def _read(path, cycles="expand"):
    return parse_lathe_program(path, load_machine(LATHE), "keep", None, "linuxcnc", cycles=cycles)[0]


def _moves(tmp_path, cycle, **kw):
    src = tmp_path / "p.ngc"
    src.write_text(_program(cycle, **kw))
    prog = _read(src)
    moves = prog.moves[1:-1]  # the G0 to the start before, the G0 after
    return [(m.kind, m.end[0], m.end[1]) for m in moves]


def _g70_reference(d, e, p):
    out = []
    for k in range(p, 0, -1):
        delta = (k - 1) * (d - e) / p + e
        out += [("rapid", X0, Z0), ("rapid", A + delta, Z0), ("linear", A + delta, ZF + delta),
                ("linear", X0, ZF + delta)]
    return out


def _g71_reference(d, i, r):
    out, x = [("rapid", X0, Z0)], X0
    while x > A + d:
        out += [("rapid", x, Z0), ("linear", x, ZF + d), ("rapid", x + r, ZF + d + r), ("rapid", x + r, Z0 - r),
                ("rapid", x, Z0)]
        x -= i
    return out + [("rapid", A + d, Z0), ("linear", A + d, ZF + d), ("linear", X0, ZF + d)]


def _same(got, ref):
    assert [g[0] for g in got] == [r[0] for r in ref]
    assert np.abs(np.array([g[1:] for g in got]) - np.array([r[1:] for r in ref])).max() <= TOL_WRITTEN_MM


@pytest.mark.parametrize("d, e, p", [(0.0, 0.0, 1), (1.0, 0.0, 2), (1.5, 0.25, 3)])
def test_g70_expanded_passes_are_the_reference_offsets(tmp_path, d, e, p):
    _same(_moves(tmp_path, f"G70 Q100 X{X0} Z{Z0} D{d} E{e} P{p}"), _g70_reference(d, e, p))


@pytest.mark.parametrize("d, i, r", [(0.5, 2.0, 0.5), (0.0, 3.0, 0.3), (0.25, 1.5, 0.0)])
def test_g71_expanded_levels_are_the_reference_roughing(tmp_path, d, i, r):
    got = _moves(tmp_path, f"G71 Q100 X{X0} Z{Z0} D{d} I{i} R{r}")
    _same(got, _g71_reference(d, i, r))


FACE = ("(faced shoulder, LinuxCNC G72)\nG21 G18 G90 G8\nG54\nS800 M3\nF200\n"
        "O100 SUB\n  G0 Z0 (onto the face)\n  G1 X10\n  G1 Z5\nO100 ENDSUB\nG0 X20 Z5\n{cycle}\nG0 X40 Z10\nM5\nM2\n")
"""A face at Z0 from the start's X (20) down to X10, then a Z line at X10 up to the start's Z (5)."""


@pytest.mark.parametrize("d, i, r", [(0.5, 2.0, 0.5), (0.0, 1.5, 0.25)])
def test_g72_expanded_levels_are_the_roughing_turned_a_quarter(tmp_path, d, i, r):
    """G72 is G71 on the contour turned a quarter: levels Z = 5 − k·I while above the face's Z + D, each a feed along
    X to the offset Z line (X10 + D), the escape by R in X and Z, back along X to the start's X − R, up to the level;
    then the last level on the offset face and up the offset Z line."""
    src = tmp_path / "p.ngc"
    src.write_text(FACE.format(cycle=f"G72 Q100 X20 Z5 D{d} I{i} R{r}"))
    got = [(m.kind, m.end[0], m.end[1]) for m in _read(src).moves[1:-1]]
    ref, z = [("rapid", 20.0, 5.0)], 5.0
    while z > 0.0 + d:
        ref += [("rapid", 20.0, z), ("linear", 10.0 + d, z), ("rapid", 10.0 + d + r, z + r), ("rapid", 20.0 - r, z + r),
                ("rapid", 20.0, z)]
        z -= i
    _same(got, ref + [("rapid", 20.0, d), ("linear", 10.0 + d, d), ("linear", 10.0 + d, 5.0)])


POCKET = ("(a shaft with a groove, LinuxCNC G71.2)\nG21 G18 G90 G8\nG54\nS800 M3\nF200\n"
          "O100 SUB\n  G0 X10\n  G1 Z-10\n  G1 X8 Z-12\n  G1 Z-16\n  G1 X10 Z-18\n  G1 Z-25\n  G1 X20\nO100 ENDSUB\n"
          "G0 X20 Z2\nG71.2 Q100 X20 Z2 D0 I1 R0.3\nG0 X40 Z10\nM5\nM2\n")
"""A shaft at X10 with a 2 mm deep groove (45° flanks from Z-10 and Z-18 to a floor at X8 from Z-12 to Z-16)."""


def test_g71_2_cuts_only_the_pocket(tmp_path):
    """G71.2 (the pockets only: after a G71.1): along the contour to the groove, then levels X = 10, 9 (I below the
    start's X, above the floor), each a feed down the left flank to the level (Z = −10 − (10 − X)), across to the
    right flank (Z = −18 + (10 − X)), the escape by R in X and Z, back to Z of the left flank − R, down to it; then
    along the floor, up the right flank and on along the contour."""
    src = tmp_path / "p.ngc"
    src.write_text(POCKET)
    got = [(m.kind, m.end[0], m.end[1]) for m in _read(src).moves[1:-1]]
    r, ref = 0.3, [("rapid", 20.0, 2.0), ("rapid", 10.0, 2.0), ("linear", 10.0, -10.0)]
    for x in (10.0, 9.0):
        left, right = -10.0 - (10.0 - x), -18.0 + (10.0 - x)
        ref += [("linear", x, left), ("linear", x, right), ("rapid", x + r, right + r), ("rapid", x + r, left - r),
                ("linear", x, left)]
    _same(got, ref + [("linear", 8.0, -12.0), ("linear", 8.0, -16.0), ("linear", 10.0, -18.0), ("linear", 10.0, -25.0),
                      ("linear", 20.0, -25.0)])


ARC = ("(turned shaft with a rounded shoulder, LinuxCNC G71 and G70)\nG21 G18 G90 G8\nG54\nS800 M3\nF150\n"
       "O200 SUB\n  G0 X12\n  G1 Z-10\n  G1 X16 Z-14\n  G1 Z-25\n  G3 X19 Z-28 I0 K-3\n  G1 Z-40\n  G1 X24\n"
       "O200 ENDSUB\nG0 X24 Z2\nG71 Q200 X24 Z2 D0.4 I1.5 R0.5\nG70 Q200 X24 Z2 D0.4 P2\nG0 X40 Z10\nM5\nM2\n")
"""A shaft: X12 (radius) to Z-10, a taper to X16, a rounded shoulder (G3, radius 3) up to X19, a face to X24."""
ARC_CONTOUR = [(12.0, 2.0, None), (12.0, -10.0, None), (16.0, -14.0, None), (16.0, -25.0, None),
               (19.0, -28.0, (16.0, -28.0)), (19.0, -40.0, None), (24.0, -40.0, None)]
"""The contour's points (X radius, Z mm; an arc's centre) as the reference reads it from O200."""


@pytest.mark.parametrize("mode, arc", [("G90", "G3 X19 Z-28 I0 K-3"), ("G90", "G3 X19 Z-28 R3"),
                                       ("G90 G90.1", "G3 X19 Z-28 I16 K-28")])
def test_g70_last_pass_is_the_contour_with_its_arc(tmp_path, mode, arc):
    """The shoulder as I K (incremental centre), R (the centre on G3's side) or absolute I K (G90.1 in force before
    the cycle: the cycle does not run its contour's modal words): the same arc, written in the mode in force."""
    src = tmp_path / "p.ngc"
    src.write_text(ARC.replace("G3 X19 Z-28 I0 K-3", arc).replace("G18 G90 G8", f"G18 {mode} G8"))
    prog = _read(src)
    last = prog.moves[-len(ARC_CONTOUR) - 2:-1]  # the last pass (distance 0), before the G0 after the cycle
    assert [m.kind for m in last] == ["rapid", "rapid"] + ["linear"] * 3 + ["arc"] + ["linear"] * 2
    assert np.allclose(last[0].end, (24.0, 2.0), rtol=0, atol=TOL_WRITTEN_MM)  # the start point
    for m, (x, z, c) in zip(last[1:], ARC_CONTOUR):
        assert np.allclose(m.end, (x, z), rtol=0, atol=TOL_WRITTEN_MM)
        if c is not None:  # G18: the arc's u column is Z, its v column X
            assert (m.arc["ju"], m.arc["jv"]) == (1, 0)
            assert np.allclose((m.arc["vc"], m.arc["uc"]), c, rtol=0, atol=TOL_WRITTEN_MM)
            assert abs(m.arc["r0"] - 3.0) <= TOL_WRITTEN_MM and abs(m.arc["r1"] - 3.0) <= TOL_WRITTEN_MM
            assert abs(m.arc["sweep"] - np.pi / 2) <= 1e-9  # a quarter turn, as G3 from (16, -25) about (16, -28)


def test_g71_g70_compensated_every_point_true(tmp_path):
    rc, src, written, truth = _compensate(tmp_path, ARC, ("--expand-cycles",))
    assert rc == 0
    p_src, p_out = _read(src), _read(written, "keep")
    lathe, field = _field(truth)
    m_src = [m for m in p_src.moves if m.compensate]
    assert len(m_src) > 20  # the roughing levels' cuts and both finishing passes (their rapids kept as written)
    errs, missed = lathe_points_reached(field, lathe, m_src, [m for m in p_out.moves if m.compensate],
                                        (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None and len(errs) == len(m_src) and max(errs) <= TOL_POINT_UM
    unc, _ = lathe_points_reached(field, lathe, m_src, m_src, (0.0, PART_Z_MM), 1e9)
    assert max(unc) > 10 * TOL_POINT_UM  # the truth moves the programmed points: the check can fail
    non_moves = [ln for ln, c in zip(p_out.lines, p_out.classes) if c != "move" and not ln.startswith("(volcomp:")]
    assert non_moves == [ln for ln, c in zip(p_src.lines, p_src.classes) if c != "move"]


def test_g70_under_g42_1_is_read_as_under_g42_with_the_tool_table_radius(tmp_path):
    """LinuxCNC runs G70 under cutter compensation (``convert_g7x`` refuses only G71/G72 so), its moves offset by
    its compensation as written moves are: expanded, each point compensated as programmed (TRUE within the
    tolerance), the written program and the reported bound the same as under ``G42 D5`` with tool 5's radius 0.4 mm
    from the tool table (``G42.1 D0.8``: D the diameter)."""
    runs = {}
    for key, comp in (("dyn", "G42.1 D0.8 L3"), ("table", "G42 D5")):
        (tmp_path / key).mkdir()
        (tmp_path / key / "t.csv").write_text("tool,x_mm,z_mm,radius_mm\n5,0,0,0.4\n")
        text = ARC.replace("\nG70", f"\n{comp}\nG70").replace("G0 X40 Z10", "G40 G0 X40 Z10")
        rc, src, written, truth = _compensate(tmp_path / key, text, ("--expand-cycles", "--tool-table",
                                                                     str(tmp_path / key / "t.csv")))
        assert rc == 0
        summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
        runs[key] = (src, written, truth, summary)
    src, written, truth, dyn = runs["dyn"]
    p_src, p_out = _read(src), _read(written, "keep")
    lathe, field = _field(truth)
    m_src = [m for m in p_src.moves if m.compensate]
    errs, missed = lathe_points_reached(field, lathe, m_src, [m for m in p_out.moves if m.compensate],
                                        (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None and len(errs) == len(m_src) > 20 and max(errs) <= TOL_POINT_UM
    table_out = _read(runs["table"][1], "keep")
    assert np.abs(np.array([m.end for m in p_out.moves]) - np.array([m.end for m in table_out.moves])).max() <= \
        TOL_WRITTEN_MM
    bound = runs["table"][3]["cutter_radius_bound_um"]
    assert bound > 0.01 and abs(dyn["cutter_radius_bound_um"] - bound) <= 1e-9 * bound
    assert dyn["dynamic_cutter_radii_mm"] == ["line 17 (expanded line 56): 0.4"]  # the G71's 49 moves before it


def test_frames_follow_the_lines_after_expanded_cycles(tmp_path):
    """The cycles' notes are events added after the reading (out of line order): the frames still follow the lines,
    so the G71's moves run at tool 1's Z offset, the G70's (after ``T2 M6 G43``) at tool 2's."""
    from compensation.nc_state import program_frames, read_tool_table, read_work_offsets
    src = tmp_path / "p.ngc"
    src.write_text(ARC.replace("G0 X24 Z2\n", "T1 M6 G43\nG0 X24 Z2\n").replace("\nG70", "\nT2 M6 G43\nG70"))
    (tmp_path / "t.csv").write_text("tool,x_mm,z_mm,radius_mm\n1,0,10,0\n2,0,20,0\n")
    (tmp_path / "o.csv").write_text("system,x_mm,y_mm,z_mm\nG54,0,0,0\n")
    prog = _read(src)
    frames = program_frames(prog, read_work_offsets(tmp_path / "o.csv"), read_tool_table(tmp_path / "t.csv"))
    z = frames.lathe_tool([m.index for m in prog.moves])[:, 1]
    t2 = next(i for i, ln in enumerate(prog.lines) if ln.startswith("T2"))
    before = np.array([m.index < t2 for m in prog.moves])
    assert before.sum() > 20 and np.all(z[before] == 10.0) and np.all(z[~before] == 20.0)


@pytest.mark.parametrize("old,new,where", [
    ("D0.5 I2 R0.5", "D0.5 I2 R0.5", "line 12, column 1: 'G71' (roughing cycle, contour o100) kept as a cycle"),
    ("G21 G18 G90 G8", "G21 G18 G90 G7", "line 12, column 1: 'G71' (roughing cycle) in diameter mode G7"),
    ("G21 G18 G90 G8", "G21 G17 G90 G8", "line 12, column 1: 'G71' (roughing cycle) in a plane other than G18"),
    ("G0 X20 Z2", "G0 X20 Z2\nG91", "line 13, column 1: 'G71' (roughing cycle) under G91"),
    ("Q100", "Q200", "line 12, column 5: 'Q200': no subroutine o200 defined before the G71"),
    (" R0.5", " R0.5 F100", "line 12, column 30: 'F100' on a G71 line"),
    (" R0.5", " R0.5 U1", "line 12, column 30: 'U1' on a G71 line"),
    (" I2", " I0", "line 12, column 22: 'I0' on a G71 line: the depth of cut must be > 0"),
    ("G0 X20 Z2\n", "G0 X20 Z2\nG41.1 D0.8\n", "line 13, column 1: 'G71' (roughing cycle) with cutter compensation "
                                             "G41.1 on (LinuxCNC's error: 'G71.0 cannot be used with cutter"),
    ("  G1 Z-20 (", "  G1 Z-20 F50 (",
     "line 12, column 1: line 8 (the contour o100), column 11: 'F50' in a G7x contour"),
    ("  G0 X10 (onto", "  X10 (onto",
     "line 12, column 1: line 7 (the contour o100): the contour moves before it names"),
    ("  G1 X20", "  G1 X20\n  #<a> = 3", "line 10, column 3: in o100, the contour of the G7x cycle on"),
    ("  G1 X20", "  G1 X15 Z-10", "line 12, column 1: 'G71' (roughing cycle, contour o100): not computed as LinuxCNC "
                                  "computes it: the reference's 'Not monotonic'"),
])
def test_g71_refusals_name_line_column_word(tmp_path, old, new, where):
    src = tmp_path / "p.ngc"
    src.write_text(_program("G71 Q100 X20 Z2 D0.5 I2 R0.5").replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        _read(src, "keep" if "kept" in where else "expand")
    assert where in str(exc.value), str(exc.value)
    if "kept" in where:
        assert "use --expand-cycles" in str(exc.value)


LOOPED = ("  G0 X{a:g}\n  O110 REPEAT [3]\n  O120 IF [1 GT 2]\n  G1 Z{zf:g} A0.2\n  O120 ENDIF\n  O110 ENDREPEAT\n"
          "  O130 CALL\n  (onto")
"""The step's contour with O-word lines around its Z line (a loop of 3, a false if, a call) and an A word on it."""


@pytest.mark.parametrize("cycle", ["G71 Q100 X20 Z2 D0.5 I2 R0.5", "G70 Q100 X20 Z2 D1 P2"])
def test_contour_o_words_read_not_run_as_the_interpreter_reads_them(tmp_path, cycle):
    """LinuxCNC builds the contour with ``Interp::read`` alone (interp_g7x.cc's ``convert_g7x``: parse, never
    execute, until the first endsub): the loop's body is read once, the false if's body too, the call not made, the A
    word skipped; the moves are those of the flat contour (G0 X10, G1 Z-20, G1 X20), the summary names the lines."""
    flat = _moves(tmp_path, cycle)
    src = tmp_path / "looped.ngc"
    text = _program(cycle).replace("O100 SUB", "O130 SUB\nO130 ENDSUB\nO100 SUB", 1)
    src.write_text(text.replace("  G0 X10 (onto", LOOPED.format(a=A, zf=ZF), 1).replace("  G1 Z-20 (along the "
                                                                                               "step)\n", "", 1))
    prog = _read(src)
    got = [(m.kind, m.end[0], m.end[1]) for m in prog.moves[1:-1]]
    _same(got, flat)
    note = next(e[4].text(prog) for e in prog.events if e[2] == "lathe-cycle")
    assert "O-word lines 10, 11, 13, 14, 15 read and not run" in note, note
