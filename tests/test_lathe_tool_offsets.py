"""Lathe tool offsets (compensation/nc_state.py, turning.py): a lathe tool's X and Z offsets, from LinuxCNC's
tool table (``T1 P1 X-40 Z+120 Q2``: "the X and Z offsets of a lathe tool", applied by ``G43`` after the tool
change, LinuxCNC "Lathe User Information") or a CSV ``tool,x_mm,z_mm[,radius_mm]``, and Fanuc/Haas turning's
``TttOO`` word (tool ``tt``, offset register ``OO``; ``OO = 00`` cancels; Fanuc 0i-TF "Tool offset").

The controller drives machine X = program X + work offset + tool X (and the same along Z), and the tool tip is
the chain's tool point moved back by the offset at the end of the tool side: the nominal tip is the programmed
one, but the angular errors of the carriage and cross slide act on the offset's Abbe arm. Every program here is
written from that wording; an accepted one is compensated on a simulated truth (a seeded element set, ±10 μm /
μrad) and checked independently: the frames read from the test program's own words by patterns (not by the
reader), every non-motion line byte-identical, every programmed end point reproduced by the TRUE machine over
the turn within 1 μm."""
import json
import re

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import (field_with_tool, machine_with_lathe_tool, program_frames, read_tool_table,
                                   read_work_offsets)
from compensation.turning import parse_lathe_program, solve_turning, surface_residual_um
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups

LATHE = "lathe-xzc"
WORK_Z_MM = 300.0
"""G54 of the tests: the part zero 300 mm along the bed (X 0: the spindle axis)."""
TOOLS = {1: (-40.0, 120.0), 2: (25.0, 80.0)}
"""The tool table of the tests: tool -> (X, Z) offset mm (a long Abbe arm on purpose)."""
TBL = ("T1 P1 X-40.0 Z+120.0 D0.8 I95.0 J155.0 Q2 ;roughing, front tool post\n"
       "T2 P2 X+25.0 Z+80.0 D0.4 Q3 ;finishing\n")
CSV = "tool,x_mm,z_mm,radius_mm\n1,-40,120,0.4\n2,25,80,0.2\n"
PROGRAM = """(turning with two tools: LinuxCNC loads a tool with T M6 and applies its X and Z offsets with G43)
G18 G21 G90 G8
T1 M6 G43
G0 X60 Z10
S800 M3
G1 X50 Z0 F0.2
G1 Z-40
G2 X60 Z-50 I10 K0
G1 X70
G0 X80 Z10
T2 M6 G43
G0 X55 Z5
G1 X45 Z-5
G1 Z-30
G0 X80
G49
M5
M30
"""
ELEMENT_SCALE_UM = 10.0
TOL_NOMINAL_MM = 1e-9
"""The nominal tip at the tool's offsets moved by the offsets is the programmed one: exact to round-off."""
TOL_LINEAR_UM = 1e-6
"""The tip error is linear in the offset (a rigid body's error, (R − I)·a, is linear in the arm a)."""
IGNORED_MIN_UM = 2.0
"""The tool offsets ignored, the TRUE residual is microns (observed 4.5 μm with the seed below: the
element set's angular errors, ±10 μrad, on the offsets' arms of 40-130 mm): well above the 1 μm bound."""


@pytest.fixture(scope="module")
def lathe():
    return load_machine(LATHE)


@pytest.fixture(scope="module")
def truth_els(lathe):
    return ChainElementSet.random(lathe, 101, ELEMENT_SCALE_UM, 11)


def _files(tmp_path, tools_text=TBL, name="tools.tbl"):
    (tmp_path / name).write_text(tools_text)
    (tmp_path / "offsets.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{WORK_Z_MM}\n")
    (tmp_path / "p.ngc").write_text(PROGRAM)
    return tmp_path / "p.ngc", tmp_path / "offsets.csv", tmp_path / name


def test_lathe_tool_tables_read_x_and_z(tmp_path):
    """The .tbl's X and Z (I, J, Q read and ignored) and the CSV's x_mm, z_mm give the same tools."""
    _, _, tbl = _files(tmp_path)
    (tmp_path / "t.csv").write_text(CSV)
    a, b = read_tool_table(tbl), read_tool_table(tmp_path / "t.csv")
    assert a.x_mm == b.x_mm == {t: x for t, (x, _) in TOOLS.items()}
    assert {t: v[0] for t, v in a.tools.items()} == {t: v[0] for t, v in b.tools.items()} == \
        {t: z for t, (_, z) in TOOLS.items()}


@pytest.mark.parametrize("text, where", [
    ("tool,x_mm,z_mm,length_mm\n1,1,2,3\n", "a lathe's tool table has the columns x_mm and z_mm, and no length_mm"),
    ("tool,x_mm,radius_mm\n1,1,2\n", "a lathe's tool table has the columns x_mm and z_mm"),
    ("tool,x_mm,z_mm\n1,1,2O\n", "row 2, column 3: z_mm: expected a number"),
    ("T1 P1 X-4.0 Y2.0 Z+12.0\n", "row 1, column 13: Y2: a tool offset along Y is not supported"),
])
def test_bad_lathe_tool_rows_are_refused_by_row_and_column(tmp_path, text, where):
    p = tmp_path / ("t.csv" if "," in text else "t.tbl")
    p.write_text(text)
    with pytest.raises(InputError, match=re.escape(where)):
        read_tool_table(p)


def _frames_by_hand(lines):
    """Per source line, from the program's words by pattern (not the reader): the tool (X, Z) offset in force,
    or None (LinuxCNC: ``Tn M6`` loads, ``G43`` applies the loaded tool, ``G49`` cancels)."""
    loaded, on, out = None, None, []
    for ln in lines:
        ln = re.sub(r"\(.*?\)", "", ln)
        m = re.search(r"T(\d+) M6", ln)
        loaded = int(m.group(1)) if m else loaded
        if re.search(r"G43(?![.\d])", ln):
            on = TOOLS[loaded]
        if "G49" in ln:
            on = None
        out.append(on)
    return out


def test_frames_follow_the_tool_words(tmp_path, lathe):
    prog_path, offsets, tbl = _files(tmp_path)
    prog, _ = parse_lathe_program(prog_path, lathe, "keep", None, "linuxcnc")
    frames = program_frames(prog, read_work_offsets(offsets), read_tool_table(tbl))
    by_hand = _frames_by_hand(PROGRAM.splitlines())
    for m in prog.moves:
        x, z = by_hand[m.index]
        assert np.abs(frames.shift([m.index], prog.axis_words.words)[0] - [x, WORK_Z_MM + z]).max() <= 1e-12
    assert frames.notes["tool_x_used"] == {1: -40.0, 2: 25.0} and frames.notes["tools_used"] == {1: 120.0, 2: 80.0}


def test_the_tool_offset_is_a_translation_at_the_end_of_the_tool_side(lathe, truth_els):
    """machine X, Z = program X, Z + offset with the chain's tool point moved back by the offset: the nominal
    tip does not move, the error does (the angular errors act on the arm), linearly in the offset."""
    rng = np.random.default_rng(5)
    ax = np.stack([rng.uniform(20, 150, 200), rng.uniform(150, 350, 200), rng.uniform(0, 360, 200)], axis=1)
    f0 = ChainField(lathe, truth_els)
    errs = {}
    for a in ((-40.0, 120.0), (25.0, 80.0), (-15.0, 200.0)):
        mt = machine_with_lathe_tool(lathe, *a)
        q = ax + [a[0], a[1], 0.0]
        assert np.abs(mt.nominal(q) - lathe.nominal(ax)).max() < TOL_NOMINAL_MM
        errs[a] = field_with_tool(f0, mt).predict(ax) - f0.predict(ax)  # the arm's part, at the same axes
        assert np.abs(errs[a]).max() > 0.1
    s = errs[(-40.0, 120.0)] + errs[(25.0, 80.0)]  # (−15, 200) is their sum
    assert np.abs(s - errs[(-15.0, 200.0)]).max() < TOL_LINEAR_UM


def _compensated(tmp_path, tools_file, offsets):
    truth = tmp_path / "truth.json"
    if not truth.exists():
        ChainElementSet.random(load_machine(LATHE), 101, ELEMENT_SCALE_UM, 11).save(truth)
    out = tmp_path / f"out_{tools_file.suffix[1:]}"
    assert main(["compensate", str(tmp_path / "p.ngc"), "--machine", LATHE, "--model", str(truth), "--truth",
                 str(truth), "--method", "exact", "--dialect", "linuxcnc", "--work-offsets", str(offsets),
                 "--tool-table", str(tools_file), "--out", str(out)]) == 0
    return out / "p.ngc", json.loads((out / "compensate_summary.json").read_text())["files"][0]


@pytest.mark.parametrize("table", ["tools.tbl", "tools.csv"])
def test_turning_with_tool_offsets_reaches_every_point(tmp_path, lathe, truth_els, table):
    """Run as LinuxCNC runs the output: machine X, Z = written + G54 + the tool's offsets (by hand); the TRUE
    machine's tip at the tool, averaged over the turn, on every programmed end point within 1 μm."""
    _, offsets, tools = _files(tmp_path, TBL if table.endswith("tbl") else CSV, table)
    out_file, entry = _compensated(tmp_path, tools, offsets)
    src, out = (parse_lathe_program(p, lathe, "keep", None, "linuxcnc")[0] for p in (tmp_path / "p.ngc", out_file))
    comp = {m.index: m for m in src.moves if m.compensate}
    out_moves = {m.index: m for m in out.moves}
    frame = _frames_by_hand(src.lines)
    errs = []
    for i, g in enumerate(_groups(src.lines, out.lines)):
        if i not in comp:
            assert [out.lines[k] for k in g] == [src.lines[i]]  # byte-identical
            continue
        x, z = frame[i]
        shift = np.array([x, WORK_Z_MM + z, 0.0])
        mt = machine_with_lathe_tool(lathe, x, z)
        q = np.append(out_moves[g[-1]].end, 0.0) + shift
        want = np.append(comp[i].end, 0.0) + shift
        mean, _ = surface_residual_um(ChainField(mt, truth_els), mt, q[None], want[None])
        errs.append(np.abs(mean).max())
    assert len(errs) == 6 and max(errs) <= TOL_POINT_UM, errs
    assert entry["turning"]["true"]["max_um"] <= TOL_POINT_UM < entry["turning"]["true_uncompensated"]["max_um"]


def test_the_tool_offsets_matter(tmp_path, lathe, truth_els):
    """The same program compensated with the tools' offsets ignored in the chain (the tool point the machine
    file's own, the axes shifted as the controller shifts them) misses by microns; with them it does not.
    The model is the truth (nothing else differs)."""
    from compensation.app.workflows.compensate import CompensateSettings, solve_paths
    from compensation.app.workflows.compensate_paths import read_tool_path
    prog, offsets, tools = _files(tmp_path)
    s = CompensateSettings("exact", "", tmp_path, work_offsets=read_work_offsets(offsets),
                           tool_table=read_tool_table(tools), dialect="linuxcnc")
    field_ = ChainField(lathe, truth_els)
    tp = read_tool_path(prog, lathe, s, field_)
    res, _, _, _ = solve_paths([tp], field_, field_, lathe, s)[0]
    ignored_q, _, _, _, _ = solve_turning(field_, lathe, tp.axes, ball_um=250.0)  # the base chain's tool point
    worst = {}
    for name, q in (("used", res.axes), ("ignored", ignored_q)):
        errs = []
        for x, z in {tuple(r) for r in tp.tool_xz}:
            idx = np.flatnonzero((tp.tool_xz == (x, z)).all(axis=1))
            mt = machine_with_lathe_tool(lathe, x, z)
            errs.append(np.abs(surface_residual_um(ChainField(mt, truth_els), mt, q[idx], tp.axes[idx])[0]).max())
        worst[name] = max(errs)
    print(f"TRUE residual over the turn, max: tool offsets ignored {worst['ignored']:.3f} um, used {worst['used']:.2e} um")
    assert worst["used"] <= TOL_POINT_UM < IGNORED_MIN_UM < worst["ignored"], worst


# ---------------------------------------------------------------------------- Fanuc / Haas TttOO
FANUC = "G18 G21 G40\nT0101\nG0 X60. Z10.\nG1 Z-20. F0.2\nT0100\nG0 X80. Z10.\nT0202\nG0 X50. Z5.\nM30\n"
FANUC_SHIFT = {3: (-40.0, 120.0), 4: (-40.0, 120.0), 6: (0.0, 0.0), 8: (25.0, 80.0)}
"""1-based lines: the offset register in force (T0101: offset 1; T0100: none; T0202: offset 2)."""


@pytest.mark.parametrize("dialect", ["fanuc", "haas"])
def test_a_fanuc_lathe_t_word_selects_tool_and_offset(tmp_path, lathe, dialect):
    p = tmp_path / "f.nc"
    p.write_text(FANUC)
    (tmp_path / "t.csv").write_text(CSV)
    xz = AxisWords(LATHE, ("X", "Z"), ())
    prog = parse_program(p, axis_words=xz, dialect=dialect, lathe_x="radius")
    frames = program_frames(prog, read_work_offsets("machine"), read_tool_table(tmp_path / "t.csv"))
    for m in prog.moves:
        assert np.abs(frames.shift([m.index], ("X", "Z"))[0] - FANUC_SHIFT[m.index + 1]).max() <= 1e-12
    p.write_text(FANUC.replace("T0202", "T0303"))
    prog = parse_program(p, axis_words=xz, dialect=dialect, lathe_x="radius")
    with pytest.raises(InputError) as err:
        program_frames(prog, read_work_offsets("machine"), read_tool_table(tmp_path / "t.csv"))
    msg = str(err.value)
    assert msg.startswith(f"{p}: line 7, column 1: 'T0303': lathe tool offset 03: tool 3 is not known") and \
        "--tool-table" in msg and len(msg) - len(str(tmp_path)) < 300, msg


def test_a_four_digit_t_word_stays_refused_on_a_lathe_with_linuxcnc_and_is_a_tool_on_a_mill(tmp_path):
    """On a mill (X, Y and Z) T only selects the tool (Fanuc: tool 101; its length comes from G43 H); on a lathe
    without a dialect that reads TttOO it may select an offset: refused."""
    p = tmp_path / "m.nc"
    p.write_text("G21 G90\nT0101 M6\nG0 X1 Y1 Z1\nG1 X2 F100\nM30\n")
    prog = parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="fanuc")
    assert [e for e in prog.events if e[2] == "tool"] == []  # no offset selected by the T word
    p.write_text("G18 G21 G90\nT0101\nG0 X1 Z1\nM30\n")
    with pytest.raises(InputError, match=r"line 2, column 1: 'T0101': a T word of more than 2 digits"):
        parse_program(p, axis_words=AxisWords(LATHE, ("X", "Z"), ()), dialect="linuxcnc")


def test_a_tool_offset_in_c_axis_mode_is_refused(tmp_path, lathe, truth_els):
    """C-axis mode (the spindle stopped, C positioned) is solved by the chain method at the machine file's tool:
    a lathe tool offset there is refused naming the line and what to do, not solved at the wrong tool point."""
    from compensation.app.validate import UsageError
    from compensation.app.workflows.compensate import CompensateSettings
    from compensation.app.workflows.compensate_paths import read_tool_path
    _, offsets, tools = _files(tmp_path)
    p = tmp_path / "c.ngc"
    p.write_text("G18 G21 G90 G8\nT1 M6 G43\nG0 X60 Z10 C0\nG1 X50 Z0 C90 F100\nM30\n")
    s = CompensateSettings("exact", "", tmp_path, work_offsets=read_work_offsets(offsets),
                           tool_table=read_tool_table(tools), dialect="linuxcnc")
    with pytest.raises(UsageError, match=r"c\.ngc: line 4: a lathe tool offset in C-axis mode"):
        read_tool_path(p, lathe, s, ChainField(lathe, truth_els))


FANUC_TURNING = """%
O1001 (TURNING WITH TWO TOOLS: T0101 ROUGHING, T0202 FINISHING)
G18 G21 G40 G97
T0101
G96 S180 M03
G00 X62. Z5.
G01 X50. Z0 F0.2
G01 Z-40.
G02 X70. Z-50. R10.
G01 X80.
G00 X100. Z10.
T0100
T0202
G00 X58. Z5.
G01 X46. Z-5.
G01 Z-30.
G00 X100.
M05
M30
%
"""
"""A Fanuc turning program (X diameters, the control's parameter; TttOO: tool tt with offset register OO from
its line, OO = 00 none)."""


def _fanuc_frames(lines):
    """Per source line, by pattern: the offset register in force ((X, Z) of the CSV's rows), or None."""
    on, out = None, []
    for ln in lines:
        m = re.search(r"\bT(\d\d)(\d\d)\b", re.sub(r"\(.*?\)", "", ln))
        if m:
            on = TOOLS[int(m.group(2))] if int(m.group(2)) else None
        out.append(on)
    return out


def test_a_fanuc_lathe_program_with_tttoo_and_diameters_reaches_every_point(tmp_path, lathe, truth_els):
    """--lathe-x diameter: X read halved (and written back doubled); T0101 / T0202 at the CSV's registers; run as
    the control runs the output: machine X, Z = written (X halved) + G54 + the register's offsets; every programmed
    end within 1 μm over the turn, every other line byte-identical. Without --lathe-x the first X is refused."""
    _, offsets, tools = _files(tmp_path, CSV, "tools.csv")
    src = tmp_path / "f.nc"
    src.write_text(FANUC_TURNING)
    truth = tmp_path / "truth.json"
    ChainElementSet.random(lathe, 101, ELEMENT_SCALE_UM, 11).save(truth)
    args = ["compensate", str(src), "--machine", LATHE, "--model", str(truth), "--truth", str(truth), "--method",
            "exact", "--dialect", "fanuc", "--work-offsets", str(offsets), "--tool-table", str(tools)]
    assert main(args + ["--out", str(tmp_path / "refused")]) != 0
    with pytest.raises(InputError, match=r"line 6, column 5: 'X62\.': on a fanuc lathe X .* --lathe-x diameter\|radius"):
        parse_lathe_program(src, lathe, "keep", None, "fanuc")
    assert main(args + ["--lathe-x", "diameter", "--out", str(tmp_path / "out")]) == 0
    out_file = tmp_path / "out" / src.name
    p_src, p_out = (parse_lathe_program(p, lathe, "keep", None, "fanuc", lathe_x="diameter")[0] for p in (src, out_file))
    comp = {m.index: m for m in p_src.moves if m.compensate}
    out_moves = {m.index: m for m in p_out.moves}
    frame = _fanuc_frames(p_src.lines)
    head = sum(1 for ln in p_out.lines if ln.startswith("(volcomp"))  # the writer's notes after the O line
    out_lines = p_out.lines[:2] + p_out.lines[2 + head:]
    assert [ln for ln in p_out.lines[2:2 + head]] == [ln for ln in p_out.lines if ln.startswith("(volcomp")]
    errs = []
    for i, g in enumerate(_groups(p_src.lines, out_lines)):
        if i not in comp:
            assert [out_lines[k] for k in g] == [p_src.lines[i]]  # byte-identical
            continue
        x, z = frame[i]
        shift = np.array([x, WORK_Z_MM + z, 0.0])
        mt = machine_with_lathe_tool(lathe, x, z)
        last = out_lines[g[-1]]
        xw = float(re.search(r"X(-?[\d.]+)", last).group(1)) / 2.0  # the diameter written, halved by hand
        zw = float(re.search(r"Z(-?[\d.]+)", last).group(1))
        xs = float(re.search(r"X(-?[\d.]+)", p_src.lines[i]).group(1)) / 2.0 if "X" in p_src.lines[i] else \
            comp[i].end[0]
        q = np.array([xw, zw, 0.0]) + shift
        want = np.array([xs, comp[i].end[1], 0.0]) + shift
        mean, _ = surface_residual_um(ChainField(mt, truth_els), mt, q[None], want[None])
        errs.append(np.abs(mean).max())
    assert len(errs) == 6 and max(errs) <= TOL_POINT_UM, errs
