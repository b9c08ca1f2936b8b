"""Tool and work-offset words read exactly or refused by name (compensation/gcode_state.py, nc_state.py,
nc_polar.py, nc_cycles.py): LinuxCNC's rotated work system (``G10 L2 R``, a ``.var``'s rotation), the ``G52``
local shift, mill tool numbers of three digits, polar words on canned-cycle lines, ``G54.2`` and a ``G43``
without ``H``.

The programs are written here from the controllers' manuals (LinuxCNC G-code reference "G10 L2": "R - rotation
of the XY axis around the Z axis", "G52 local offsets", "Polar coordinates", "Canned cycles: L repeats"; Fanuc
0i-MF "Local coordinate system (G52)": "G52 IP_; IP_ the origin of the local coordinate system in the workpiece
coordinate system", "G52 IP0 cancels"). The accepted ones are compensated on mill-xyz against a simulated truth and
checked independently of the reader's frames: the frame of every line is worked out here from the program's
words, every non-motion line must be byte-identical, and the TRUE machine at the written axis words must reach the
programmed point within 1 μm."""
import math
import re

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import machine_with_tool, program_frames, read_tool_table, read_work_offsets
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups

ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), a real mill's size (tests/test_work_offsets.py)."""
TOL_FRAME_MM = 1e-9
"""A frame worked out by hand vs the reader's: round-off on offsets of a few hundred mm."""
WORK_MM = np.array([200.0, 100.0, -150.0])
"""G54 of the rotated programs (mill-xyz: the part inside the strokes)."""
ROT_DEG = 30.0
MISSED_MIN_UM = 5.0
"""The same written program judged with the rotation left out of the frames (the corrections then act unturned)
must miss by more than this: the check has teeth (observed 12-20 μm with ±10 μm truth elements)."""
TOL_HOLE_MM = 5e-7
"""The cycle pass writes a hole's X Y to 6 decimals (mm): half the last digit."""

ROTATED = """G21 G90 G17
G10 L2 P1 X200 Y100 Z-150 R30
G54
G0 X0 Y0 Z20
G1 X50 Y0 Z-2 F300
G1 X50 Y30
G2 X20 Y60 I-30 J0
G1 X0 Y60
G18 G2 X-20 Z-22 I-10 K-10
G17 G0 Z20
M2
"""
"""A LinuxCNC program in G54 set by its own ``G10 L2 P1 ... R30``: every point turned 30° about G54's origin, then
placed at (200, 100, -150); a G17 arc, and a G18 arc (a tilted arc in the machine: written as chords, as every arc)."""


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture()
def truth_file(tmp_path, mill):
    return ChainElementSet.random(mill, 101, ELEMENT_SCALE_UM, 11).save(tmp_path / "truth.json")


def _turn(p, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]])


def _compensate(tmp_path, text, truth_file, name="p.ngc", dialect="linuxcnc", offsets=None, tools=None):
    """``volcomp compensate`` of ``text`` (``offsets`` None: the program's own G10 L2 lines place it)."""
    prog = tmp_path / name
    prog.write_text(text)
    extra = (["--tool-table", str(tools)] if tools else []) + (["--work-offsets", str(offsets)] if offsets else [])
    rc = main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(truth_file), "--truth", str(truth_file),
               "--method", "exact", "--out", str(tmp_path / "o"), "--dialect", dialect, *extra])
    return rc, prog, tmp_path / "o" / name


def _errors_um(prog, out, mill, truth_file, frame_of, dialect="linuxcnc", tool_of=None):
    """|TRUE tool point − programmed point| (μm) at the end of every compensated move; ``frame_of(line0)``:
    ``(rotation deg, shift (3,))`` worked out by the test; ``tool_of(line0)``: the tool length (None: the file's).
    Every other line must be byte-identical."""
    aw = AxisWords.of(mill)
    p_src = parse_program(prog, axis_words=aw, fast=False, dialect=dialect)
    p_out = parse_program(out, axis_words=aw, fast=False, dialect=dialect)
    src, dst = p_src.lines, p_out.lines
    moves_src = {m.index: m for m in p_src.moves if m.compensate}
    moves_out = {m.index: m for m in p_out.moves}
    els = ChainElementSet.load(truth_file, mill)
    errs = []
    for i, g in enumerate(_groups(src, dst)):
        if i not in moves_src:
            assert [dst[k] for k in g] == [src[i]]
            continue
        deg, shift = frame_of(i)
        length = tool_of(i) if tool_of is not None else None
        mt = machine_with_tool(mill, length) if length is not None else mill
        q = _turn(moves_out[g[-1]].end, deg) + shift
        target = mt.nominal((_turn(moves_src[i].end, deg) + shift)[None])[0]
        tip = mt.nominal(q[None])[0] + ChainField(mt, els).predict(q[None])[0] * 1e-3
        errs.append(np.linalg.norm(tip - target) * 1e3)
    return np.array(errs)


# ---------------------------------------------------------------------------- G10 L2 R: a rotated work system
def test_a_rotated_work_system_is_compensated_where_the_part_is_cut(tmp_path, mill, truth_file):
    rc, prog, out = _compensate(tmp_path, ROTATED, truth_file)
    assert rc == 0
    errs = _errors_um(prog, out, mill, truth_file, lambda i: (ROT_DEG, WORK_MM))
    assert len(errs) == 5 and errs.max() < TOL_POINT_UM
    missed = _errors_um(prog, out, mill, truth_file, lambda i: (0.0, WORK_MM))
    assert missed.max() > MISSED_MIN_UM


def test_kept_cycle_holes_in_a_rotated_work_system_reach_their_bottoms(tmp_path, mill, truth_file):
    """A G81 series in the rotated G54: the written cycle lines (X Y Z sticky), turned and offset as the controller
    does, put the TRUE tool point at every programmed hole bottom within 1 μm."""
    text = ("G21 G90 G17\nG10 L2 P1 X200 Y100 Z-150 R30\nG54\nG0 X0 Y0 Z20\nG98 G81 X40 Y10 Z-5 R2 F200\nX60 Y-20\n"
            "G80\nG0 Z20\nM2\n")
    rc, prog, out = _compensate(tmp_path, text, truth_file)
    assert rc == 0
    written = [ln for ln in out.read_text().splitlines() if "G81" in ln or ln.startswith("X")]
    els, words, errs = ChainElementSet.load(truth_file, mill), {}, []
    for ln, hole in zip(written, [(40.0, 10.0, -5.0), (60.0, -20.0, -5.0)]):
        words.update((a, float(v)) for a, v in re.findall(r"([XYZ])(-?[\d.]+)", ln))
        q = _turn([words["X"], words["Y"], words["Z"]], ROT_DEG) + WORK_MM
        tip = mill.nominal(q[None])[0] + ChainField(mill, els).predict(q[None])[0] * 1e-3
        errs.append(np.linalg.norm(tip - mill.nominal((_turn(hole, ROT_DEG) + WORK_MM)[None])[0]) * 1e3)
    assert len(written) == 2 and max(errs) < TOL_POINT_UM


def test_a_var_files_rotation_places_the_program(tmp_path, mill, truth_file):
    var = tmp_path / "o.var"
    var.write_text("5221 200.0\n5222 100.0\n5223 -150.0\n5224 0\n5225 0\n5226 0\n5227 0\n5228 0\n5229 0\n"
                   f"5230 {ROT_DEG}\n")
    text = ROTATED.replace("G10 L2 P1 X200 Y100 Z-150 R30\n", "")
    rc, prog, out = _compensate(tmp_path, text, truth_file, offsets=var)
    assert rc == 0
    errs = _errors_um(prog, out, mill, truth_file, lambda i: (ROT_DEG, WORK_MM))
    assert len(errs) == 5 and errs.max() < TOL_POINT_UM


def test_the_frames_turn_then_shift(tmp_path, mill):
    """LinuxCNC applies the rotation before the offsets: machine = R·program + offset."""
    prog = tmp_path / "p.ngc"
    prog.write_text(ROTATED)
    p = parse_program(prog, axis_words=AxisWords.of(mill), dialect="linuxcnc")
    f = program_frames(p, read_work_offsets("machine"), None)
    q = np.array([[50.0, 30.0, -2.0]])
    m = f.place([5], q, ("X", "Y", "Z"))
    assert np.abs(m[0] - (_turn(q[0], ROT_DEG) + WORK_MM)).max() < TOL_FRAME_MM
    assert np.abs(f.unplace([5], m, ("X", "Y", "Z")) - q).max() < TOL_FRAME_MM
    assert f.notes["xy_rotation_deg"] == {"G54": ROT_DEG}


@pytest.mark.parametrize("text, dialect, line, col, words", [
    ("G21 G90\nG0 X1 Y1 Z1\nG10 L20 P1 X0 Y0 R30\nG54\nG1 X2 F100\nM2\n", "linuxcnc", 3, 18, ("'R' with G10 L20",
                                                                                             "G10 L2 only")),
    ("G21 G90\nG10 L2 P1 X200 Y100 Z-150 R30\nG54\nG1 X2 Y1 Z1 F100\nM2\n", "fanuc", 2, 27, ("'R' with G10 L2",
                                                                                            "--dialect linuxcnc")),
    ("G21 G90\nG10 L2 P1 X200 Y100 Z-150 R30\nG54\nG0 X0 Y0 Z1\nG92 X5\nG1 X2 F100\nM2\n", "linuxcnc", 5, 1,
     ("'G92'", "rotated")),
    ("G21 G90\nG10 L2 P2 X200 Y100 Z-150\nG55\nG1 X2 Y1 Z1 F100\nM2\n", "linuxcnc", 3, 1, ("'G55'", "without R",
                                                                                           "rotation")),
    ("G21 G90\nG10 L2 P1 X200 Y100 Z-150\nG1 X2 Y1 Z1 F100\nM2\n", "linuxcnc", 2, 1, ("'G10 L2 P1'", "active",
                                                                                     "without R")),
])
def test_what_a_rotated_work_system_does_not_say_is_refused_by_name(tmp_path, mill, text, dialect, line, col, words):
    prog = tmp_path / "p.ngc"
    prog.write_text(text)
    with pytest.raises(InputError) as err:
        p = parse_program(prog, axis_words=AxisWords.of(mill), dialect=dialect)
        program_frames(p, None, None)
    msg = str(err.value)
    assert msg.startswith(f"{prog}: line {line}, column {col}: ") and len(msg) - len(str(prog)) < 300, msg
    assert all(w in msg for w in words), msg


def test_a_rotation_on_a_machine_without_x_and_y_is_refused(tmp_path):
    var = tmp_path / "o.var"
    var.write_text("5221 10\n5222 0\n5223 -20\n5230 15\n")
    prog = tmp_path / "p.ngc"
    prog.write_text("G18 G21 G90\nG54\nG0 X10 Z5 C0\nG1 X5 Z0 F100\nM2\n")
    p = parse_program(prog, axis_words=AxisWords("lathe-xzc", ("X", "Z", "C"), ("C",)), dialect="linuxcnc")
    with pytest.raises(InputError, match=r"p\.ngc: line 1: a rotated work system .* without X and Y axis words"):
        program_frames(p, read_work_offsets(var), None)


# ---------------------------------------------------------------------------- G52: the local shift
G52_FANUC = """%
O0052
G21 G90 G17 G40 G49 G80
G54
G0 X10. Y10. Z20.
G52 X5. Y-3.
G1 Z-1. F200.
G1 X30. Y20.
G55
G1 X1. Y2. Z3.
G52 X0 Y0 Z0
G1 X4. Y5. Z6.
G0 Z50.
M30
%
"""
"""Fanuc 0i-MF wording: the local system's origin at (5, -3) in every work system until ``G52 X0 Y0 Z0``."""
G52_SHIFT_MM = np.array([5.0, -3.0, 0.0])
G54_MM, G55_MM = np.array([200.0, 100.0, -150.0]), np.array([250.0, 120.0, -160.0])


def test_g52_shifts_every_work_system_until_it_is_cancelled(tmp_path, mill, truth_file):
    offsets = tmp_path / "offsets.csv"
    offsets.write_text("system,x_mm,y_mm,z_mm\nG54,200,100,-150\nG55,250,120,-160\n")
    rc, prog, out = _compensate(tmp_path, G52_FANUC, truth_file, name="p.nc", dialect="fanuc", offsets=offsets)
    assert rc == 0

    def frame(i):  # 0-based source lines: G52 on line 5, G55 on line 8, G52 X0 on line 10
        return 0.0, (G54_MM if i < 8 else G55_MM) + (G52_SHIFT_MM if 5 <= i < 10 else 0.0)
    errs = _errors_um(prog, out, mill, truth_file, frame, dialect="fanuc")
    assert len(errs) == 4 and errs.max() < TOL_POINT_UM


def test_linuxcnc_g52_is_the_g92_register(tmp_path, mill):
    """LinuxCNC: G52 and G92 share the offset registers: G92.1 clears a G52 shift, G92.3 restores it."""
    prog = tmp_path / "p.ngc"
    prog.write_text("G21 G90\nG54\nG0 X0 Y0 Z10\nG52 X5 Y-3\nG1 X1 F100\nG92.2\nG1 X2\nG92.3\nG1 X3\nG92.1\nG1 X4\n"
                    "M2\n")
    p = parse_program(prog, axis_words=AxisWords.of(mill), dialect="linuxcnc")
    f = program_frames(p, read_work_offsets("machine"), None)
    for line0, want in ((4, G52_SHIFT_MM), (6, 0.0), (8, G52_SHIFT_MM), (10, 0.0)):
        assert np.abs(f.shift([line0], ("X", "Y", "Z"))[0] - want).max() < TOL_FRAME_MM, line0
    assert f.notes["g52_lines"] == [4]


@pytest.mark.parametrize("text, dialect, line, col, words", [
    ("G21 G91\nG52 X5 Y-3\nM2\n", "fanuc", 2, 1, ("'G52' under G91",)),
    ("G21 G90\nG52\nM2\n", "fanuc", 2, 1, ("'G52' without axis words",)),
    ("G21 G90\nG52 X5\nG0 X1 Y1 Z1\nM2\n", "grbl", 2, 1, ("'G52'", "not supported")),
])
def test_g52_refusals_name_the_word(tmp_path, mill, text, dialect, line, col, words):
    prog = tmp_path / "p.nc"
    prog.write_text(text)
    with pytest.raises(InputError) as err:
        parse_program(prog, axis_words=AxisWords.of(mill), dialect=dialect)
    msg = str(err.value)
    assert msg.startswith(f"{prog}: line {line}, column {col}: ") and len(msg) - len(str(prog)) < 300, msg
    assert all(w in msg for w in words), msg


def test_a_move_after_the_program_end_with_a_shift_in_force_is_refused(tmp_path, truth_file, capsys):
    text = "G21 G90\nG54\nG0 X10 Y10 Z20\nG52 X5 Y-3\nG1 X10 Y10 Z5 F100\nM30\nG1 X4 Y5 Z6\n"
    rc, prog, _ = _compensate(tmp_path, text, truth_file, name="p.nc", dialect="fanuc", offsets="machine")
    assert rc == 2
    err = capsys.readouterr().err
    assert f"{prog}: line 7: a move after 'M30' of line 6, with a G52/G92 shift in force" in err


# ---------------------------------------------------------------------------- three-digit mill tool numbers
MASTERCAM_T212 = """%
O1001
G21 G90 G17 G40 G49 G80
T212 M06
G54
G0 X10. Y10.
G43 H212 Z20.
G1 Z5. F100.
G1 X20.
G0 Z20.
M30
%
"""
"""A Mastercam Fanuc post's tool call: tool 212 and its length offset H212."""


def test_a_three_digit_tool_number_on_a_mill_is_a_tool(tmp_path, mill, truth_file):
    tools = tmp_path / "tools.csv"
    tools.write_text("tool,length_mm,radius_mm\n212,130,5\n12,90,4\n")
    offsets = tmp_path / "offsets.csv"
    offsets.write_text("system,x_mm,y_mm,z_mm\nG54,200,100,-150\n")
    rc, prog, out = _compensate(tmp_path, MASTERCAM_T212, truth_file, name="p.nc", dialect="fanuc", offsets=offsets,
                                tools=tools)
    assert rc == 0
    errs = _errors_um(prog, out, mill, truth_file, lambda i: (0.0, G54_MM + [0.0, 0.0, 130.0]), dialect="fanuc",
                      tool_of=lambda i: 130.0)
    assert len(errs) == 2 and errs.max() < TOL_POINT_UM
    assert read_tool_table(tools).tools[212][0] == 130.0


# ---------------------------------------------------------------------------- polar words on cycle lines
POLAR_CIRCLE = "G21 G90 G17\nG0 X30 Y0 Z5\nG91 G81 R-3 Z-6 ^45 L8 F100\nG90 G80\nG0 Z20\nM2\n"
"""Eight holes 45° apart on the circle of radius 30 through the start point (LinuxCNC convert_cycle_xy: each repeat
turns the previous hole by ^ about the XY zero): under G91 R is from the initial level 5 (R plane 2), Z from R
(bottom -4)."""
POLAR_HOLES = [(30 * math.cos(math.radians(45 * k)), 30 * math.sin(math.radians(45 * k))) for k in range(1, 9)]
POLAR_BOTTOM_MM = -4.0


def test_polar_cycle_holes_follow_linuxcnc(tmp_path, mill):
    prog = tmp_path / "p.ngc"
    prog.write_text(POLAR_CIRCLE)
    from compensation.chain_gcode import parse_chain_program
    p = parse_chain_program(prog, mill, dialect="linuxcnc", cycles="keep")
    bottoms = [m.end for m in p.moves if m.compensate and m.end[2] == POLAR_BOTTOM_MM]
    assert len(bottoms) == len(POLAR_HOLES)
    assert np.abs(np.array(bottoms)[:, :2] - POLAR_HOLES).max() < TOL_HOLE_MM


def test_polar_cycle_holes_are_compensated_at_their_bottoms(tmp_path, mill, truth_file):
    """The written G91 series, run as the controller runs it (each hole's X Y from the one before, Z from the
    written R plane above the initial level), puts every hole's bottom where the program has it, within 1 μm."""
    offsets = tmp_path / "offsets.csv"
    offsets.write_text("system,x_mm,y_mm,z_mm\nG54,200,100,-150\n")
    rc, prog, out = _compensate(tmp_path, POLAR_CIRCLE, truth_file, offsets=offsets)
    assert rc == 0
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("(volcomp:")]
    assert lines[:2] == POLAR_CIRCLE.splitlines()[:2] and "^" not in out.read_text()
    els = ChainElementSet.load(truth_file, mill)
    x, y, initial, words, tips = 30.0, 0.0, 5.0, {}, []
    for ln in lines[2:]:
        if ln.startswith("G90 G80"):
            break
        got = dict((a, float(v)) for a, v in re.findall(r"([XYZR])(-?[\d.]+)", ln))
        words.update({a: got[a] for a in "RZ" if a in got})
        x, y = x + got["X"], y + got["Y"]
        q = np.array([x, y, initial + words["R"] + words["Z"]]) + G54_MM
        tips.append(mill.nominal(q[None])[0] + ChainField(mill, els).predict(q[None])[0] * 1e-3)
    targets = mill.nominal(np.array([[hx, hy, POLAR_BOTTOM_MM] for hx, hy in POLAR_HOLES]) + G54_MM)
    assert len(tips) == len(POLAR_HOLES)
    assert (np.linalg.norm(np.array(tips) - targets, axis=1) * 1e3).max() < TOL_POINT_UM


@pytest.mark.parametrize("text, line, col, words", [
    ("G21 G90 G17\nG0 X30 Y0 Z5\nG91 G81 R-3 Z-6 ^45 L[8] F100\nM2\n", 3, 21, ("'^'", "'L' is an expression")),
    ("G21 G90 G18\nG0 X30 Y0 Z5\nG81 R2 Z-4 ^45 F100\nM2\n", 3, 12, ("'^'", "G17 only")),
    ("G21 G90 G17\nG0 X30 Y0 Z5\nG81 X30 Y0 R2 Z-4 F100\n^45\nM2\n", 4, 1, ("'^'", "not known after line 3")),
])
def test_polar_cycle_lines_the_reader_does_not_follow_are_refused(tmp_path, mill, text, line, col, words):
    prog = tmp_path / "p.ngc"
    prog.write_text(text)
    from compensation.chain_gcode import parse_chain_program
    with pytest.raises(InputError) as err:
        parse_chain_program(prog, mill, dialect="linuxcnc", cycles="keep")
    msg = str(err.value)
    assert msg.startswith(f"{prog}: line {line}, column {col}: ") and len(msg) - len(str(prog)) < 300, msg
    assert all(w in msg for w in words), msg


# ---------------------------------------------------------------------------- G54.2, G43 without H
@pytest.mark.parametrize("text, dialect, col, words", [
    ("G21 G90\nG54.2 P1\nG0 X1 Y1 Z1\nM30\n", "fanuc", 1, ("'G54.2'", "dynamic fixture offset", "--work-offsets")),
    ("G21 G90\nT2 M6\nG43 Z5\nM30\n", "fanuc", 1, ("'G43' without H", "H number in force", "'G43 Hn'")),
    ("G21 G90\nT2 M6\nG43 Z5\nM30\n", "mach3", 1, ("'G43' without H", "mach3 needs the H number")),
    ("G21 G90\nT2 M6\nG43 Z5\nM30\n", None, 1, ("'G43' without H", "--dialect linuxcnc", "Fanuc and Haas")),
])
def test_offset_words_no_table_can_give_are_refused_by_name(tmp_path, mill, text, dialect, col, words):
    prog = tmp_path / "p.nc"
    prog.write_text(text)
    with pytest.raises(InputError) as err:
        parse_program(prog, axis_words=AxisWords.of(mill), dialect=dialect)
    msg = str(err.value)
    assert msg.startswith(f"{prog}: line 3, column {col}: ") or msg.startswith(f"{prog}: line 2, column {col}: "), msg
    assert len(msg) - len(str(prog)) < 300 and all(w in msg for w in words), msg


def test_a_bare_g43_takes_the_loaded_tool_on_linuxcnc(tmp_path, mill):
    prog = tmp_path / "p.ngc"
    prog.write_text("G21 G90\nG54\nT2 M6\nG43\nG1 X1 Y1 Z1 F100\nM2\n")
    tools = tmp_path / "t.csv"
    tools.write_text("tool,length_mm\n2,100\n")
    p = parse_program(prog, axis_words=AxisWords.of(mill), dialect="linuxcnc")
    f = program_frames(p, read_work_offsets("machine"), read_tool_table(tools))
    assert f.at([4])[1][0] == 100.0 and f.notes["tools_used"] == {2: 100.0}


def test_a_linuxcnc_cycle_starting_below_r_first_rises_to_r(tmp_path, mill):
    """LinuxCNC convert_cycle_xy: from an initial level below R a rapid up to R at the current X Y, then every hole
    clears to R (G98 or G99); here under G91 with polar repeats: R 0+2, bottom 2-6, holes at 90° and 180°."""
    prog = tmp_path / "p.ngc"
    prog.write_text("G21 G90 G17\nG0 X30 Y0 Z0\nG91 G81 R2 Z-6 ^90 L2 F100\nG90 G80\nM2\n")
    from compensation.chain_gcode import parse_chain_program
    p = parse_chain_program(prog, mill, dialect="linuxcnc", cycles="expand")
    ends = [tuple(np.round(m.end, 6)) for m in p.moves]
    assert ends == [(30.0, 0.0, 0.0), (30.0, 0.0, 2.0), (0.0, 30.0, 2.0), (0.0, 30.0, 2.0), (0.0, 30.0, -4.0),
                    (0.0, 30.0, 2.0), (-30.0, 0.0, 2.0), (-30.0, 0.0, 2.0), (-30.0, 0.0, -4.0), (-30.0, 0.0, 2.0)]
    prog.write_text("G21 G90 G17\nG0 X30 Y0 Z0\nG81 X0 Y30 R2 Z-4 F100\nG80\nM30\n")
    with pytest.raises(InputError, match=r"line 3, column 1: G81: the Z at the cycle's start \(0\) is below R \(2\)"):
        parse_chain_program(prog, mill, dialect="fanuc", cycles="keep")
