"""LinuxCNC words read exactly (compensation/gcode_state.py, turning.py): the G92 coordinate offset and its
G92.1/G92.2/G92.3 (LinuxCNC G-code reference, "G92 Coordinate System Offset": the current point reads the
values given, every work system shifts by the same amount; G92.1 clears the offset and its stored values,
G92.2 clears the offset only, G92.3 restores the stored values). Each test program is written here from that
wording; accepted programs are compensated on a simulated truth and checked independently of the reader's
frames (the offsets by hand from the manual); what cannot be read exactly is refused naming file, line,
column, word and the option."""
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import program_frames, read_work_offsets
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups

DATA = Path(__file__).resolve().parent / "data" / "linuxcnc_words"
WORK_MM = np.array([300.0, 200.0, -300.0])
"""G54 of the tests: a part zero inside mill-xyz's strokes."""
G92_BY_LINE = {**{n: (10.0, 10.0, 0.0) for n in range(4, 8)}, **{n: (0.0, 0.0, 0.0) for n in range(8, 12)},
               **{n: (10.0, 10.0, 0.0) for n in range(12, 17)}, **{n: (0.0, 0.0, 0.0) for n in range(17, 20)}}
"""g92_offsets.ngc by the manual's wording (1-based lines): line 3 ends at X10 Y10 and line 4's ``G92 X0 Y0``
makes that point read 0 0 (offset 10 10); ``G92.2`` (line 8) suspends it, ``G92.3`` (line 12) restores it,
``G92.1`` (line 17) clears it."""
MSG_MAX = 240
"""A refusal is one line under 300 characters with a plain path: its text past the test's temporary folder."""
TOL_FRAME_MM = 1e-12
"""Offsets are sums of the program's decimal values: exact to float round-off."""


@pytest.fixture()
def offsets(tmp_path):
    p = tmp_path / "offsets.csv"
    p.write_text("system,x_mm,y_mm,z_mm\nG54,%g,%g,%g\n" % tuple(WORK_MM))
    return p


def _read(text, tmp_path, dialect="linuxcnc", name="p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    return p, parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect)


def test_g92_frames_follow_the_manual(offsets):
    prog = parse_program(DATA / "g92_offsets.ngc", axis_words=AxisWords.of(load_machine("mill-xyz")),
                         dialect="linuxcnc")
    frames = program_frames(prog, read_work_offsets(offsets), None)
    for m in prog.moves:
        want = WORK_MM + (G92_BY_LINE.get(m.index + 1, (0.0, 0.0, 0.0)))
        assert np.abs(frames.at([m.index])[0][0] - want).max() <= TOL_FRAME_MM, m.index + 1
    assert frames.notes["g92_lines"] == [4, 8, 12, 17]


def test_g92_program_compensated_reaches_every_point(tmp_path, offsets):
    """The written program run as LinuxCNC runs it: the G92 lines unchanged and preceded by the same kept
    rapids, so the controller takes the same offsets (by hand, :data:`G92_BY_LINE`); every programmed end
    point is reached by the TRUE machine within 1 um and every other line is byte-identical."""
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    src = DATA / "g92_offsets.ngc"
    assert main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(tmp_path / "out"), "--dialect", "linuxcnc",
                 "--work-offsets", str(offsets)]) == 0
    aw = AxisWords.of(mill)
    p_src = parse_program(src, axis_words=aw, fast=False, dialect="linuxcnc")
    p_out = parse_program(tmp_path / "out" / src.name, axis_words=aw, fast=False, dialect="linuxcnc")
    comp = {m.index: m for m in p_src.moves if m.compensate}
    out_moves = {m.index: m for m in p_out.moves}
    field, errs = ChainField(mill, ChainElementSet.load(truth, mill)), []
    for i, g in enumerate(_groups(p_src.lines, p_out.lines)):
        if i not in comp:
            assert [p_out.lines[k] for k in g] == [p_src.lines[i]]
            continue
        shift = WORK_MM + G92_BY_LINE[i + 1]
        q = out_moves[g[-1]].end + shift
        tip = mill.nominal(q[None])[0] + field.predict(q[None])[0] * 1e-3
        errs.append(np.linalg.norm(tip - mill.nominal((comp[i].end + shift)[None])[0]) * 1e3)
    assert len(errs) == 6 and max(errs) <= TOL_POINT_UM, errs


@pytest.mark.parametrize("text, dialect, line, col, words", [
    ("G21 G90\nG0 X1 Y2 Z3\nG91\nG92 X0\nG90\nG1 X5 F100\n", "linuxcnc", 4, 1, ("'G92' under G91", "G90")),
    ("G21 G90\nG0 X1 Y2\nG92 Z0\nG1 X5 Z1 F100\n", "linuxcnc", 3, 5, ("'G92 Z0'", "not known")),
    ("G21 G90\nG0 X1 Y2 Z3\nG1 X4 F100\nG92 X0\nG1 X5\n", "linuxcnc", 4, 1,
     ("'G92' takes its offset", "line 3", "--rapids keep")),
    ("G21 G90\nG0 X1 Y2 Z3\nG92 X0\nG1 X5 F100\n", "fanuc", 3, 1, ("'G92'", "--dialect linuxcnc or grbl")),
    ("G21 G90\nG0 X1 Y2 Z3\nG92.2\nG1 X5 F100\n", "grbl", 3, 1, ("'G92.2'", "G92 and G92.1 only")),
    ("G21 G90\nG0 X1 Y2 Z3\nG92.1 X0\nG1 X5 F100\n", "linuxcnc", 3, 7, ("'X0' with G92.1",)),
])
def test_g92_refusals_name_line_column_word_and_option(tmp_path, offsets, text, dialect, line, col, words):
    with pytest.raises(InputError) as err:
        p, prog = _read(text, tmp_path, dialect)
        program_frames(prog, read_work_offsets(offsets), None)
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line {line}, column {col}: ") and len(msg) - len(str(tmp_path)) < MSG_MAX, msg
    assert all(w in msg for w in words), msg


def test_a_lathe_program_without_c_is_refused_for_its_own_word_not_for_c(tmp_path):
    """A turning program with no C word is read with X and Z: its refusal names its own word (here the
    G72 facing cycle), not the C it never uses."""
    from compensation.turning import parse_lathe_program
    p = tmp_path / "face.ngc"
    p.write_text("G18 G21 G90\nG0 X30 Z5\nS800 M3\nG1 X20 Z0 F0.2\nG72 X0 Z-2 P1 Q2\nM5\nM2\n")
    with pytest.raises(InputError) as err:
        parse_lathe_program(p, load_machine("lathe-xzc"), "keep", None, "linuxcnc")
    assert str(err.value).startswith(f"{p}: line 5, column 1: 'G72'"), str(err.value)
