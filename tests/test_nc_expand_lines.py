"""One line-number convention for the summary's notes about a program whose subprograms and parameters were
expanded (compensation/nc_expand.py ``source_line``; issue 47): every note names the source file's line, with the
expanded (flat) line and the call sites where the lines shift; a program read as it is keeps its int lines.

The program is written here (LinuxCNC O-codes, "O Codes: Subroutines", and numbered parameters): a subroutine holding
a G53 move, called twice, then G92, G38.2, G43.1 and G41.1 lines after it, so the flat program's line numbers fall
behind the source's."""
from pathlib import Path

import numpy as np

from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import program_frames, read_work_offsets
from errormap.machine import load_machine

MILL = AxisWords.of(load_machine("mill-xyz"))
SOURCE = """(source lines shift: an o-sub and a parameter)
#100 = 5.0
o100 sub
  G1 X[#100 + 10] Y10 F100
  G53 G0 Z0
  G0 Z5
o100 endsub
G21 G90 G17 G54 G40 G49
G0 X0 Y0 Z5
o100 call
G0 X5 Y5 Z5
G92 X0 Y0
o100 call
G38.2 Z-5 F50
G0 Z5
G43.1 Z10
G0 Z5
G41.1 D4
G1 X20 Y20 F100
G40
G92.1
M2
"""
FLAT = {5: (5, 10), 12: (8, None), 5.1: (10, 13), 14: (12, None), 16: (14, None), 18: (16, None), 21: (19, None)}
"""Source line: (its line in the flat program, the call site), worked out by hand: the parameter line, the
subroutine's definition and the call lines are not written; line 5 (G53, inside o100) runs at flat lines 5 and 10
(the key 5.1: its second call)."""


def _notes(tmp_path, text, name):
    (tmp_path / "off.csv").write_text("system,x_mm,y_mm,z_mm\nG54,300,200,-300\n")
    p = tmp_path / name
    p.write_text(text)
    prog = parse_program(p, axis_words=MILL, dialect="linuxcnc", rapids="keep")
    return prog, program_frames(prog, read_work_offsets(tmp_path / "off.csv"), None).notes


def _named(src):
    flat, call = FLAT[src]
    return f"{int(src)} (expanded line {flat}" + (f", called from line {call}" if call else "") + ")"


def test_notes_name_the_source_line_the_expanded_line_and_the_call(tmp_path):
    prog, notes = _notes(tmp_path, SOURCE, "p.ngc")
    assert prog.expanded is not None and not prog.expanded.line_for_line
    assert notes["g53_lines"] == [_named(5), _named(5.1)]
    assert notes["g92_lines"] == [_named(12), _named(21)]  # G92 and G92.1
    assert notes["probe_lines"] == [_named(14)]
    assert notes["dynamic_tool_lengths_mm"] == [f"line {_named(16)}: Z 10"]
    assert notes["dynamic_cutter_radii_mm"] == [f"line {_named(18)}: 2"]  # G41.1 D4: radius D/2


def test_the_flat_program_read_as_it_is_keeps_int_lines(tmp_path):
    """The expanded text holds no mark, so it is read as it is: the same notes, as ints of its own lines (the
    summary of a program that is not expanded, as before)."""
    prog, _ = _notes(tmp_path, SOURCE, "p.ngc")
    flat, notes = _notes(tmp_path, prog.expanded.text, "flat.ngc")
    assert flat.expanded is None
    assert notes["g53_lines"] == [5, 10] and notes["g92_lines"] == [8, 19] and notes["probe_lines"] == [12]
    assert notes["dynamic_tool_lengths_mm"] == ["line 14: Z 10"]
    assert notes["dynamic_cutter_radii_mm"] == ["line 16: 2"]
    assert all(type(k) is int for k in notes["g53_lines"] + notes["g92_lines"] + notes["probe_lines"])
    assert np.array_equal([m.end for m in flat.moves], [m.end for m in prog.moves])


def test_a_refusal_after_reading_names_the_source_lines(tmp_path, capsys, monkeypatch):
    """The frames' refusals (compensation.nc_state, after the reading) are re-addressed to the source as the
    reader's are: a G92 right after a G0 compensated (``--rapids compensate``) names its source line and
    that move's."""
    from compensation.app.cli import main
    from test_chain_compensate import chain_elements
    el = chain_elements(load_machine("mill-xyz"), 5).save(tmp_path / "el.json")
    (tmp_path / "off.csv").write_text("system,x_mm,y_mm,z_mm\nG54,300,200,-300\n")
    monkeypatch.chdir(tmp_path)  # a short path: the CLI shortens a long message in its middle
    Path("p.ngc").write_text(SOURCE)
    assert main(["compensate", "p.ngc", "--machine", "mill-xyz", "--model", str(el), "--method", "exact",
                 "--dialect", "linuxcnc", "--work-offsets", str(tmp_path / "off.csv"), "--rapids", "compensate",
                 "--out", str(tmp_path / "o")]) != 0
    err = capsys.readouterr().err
    assert "p.ngc: line 12, column 1: 'G92' takes its offset" in err
    assert "the end of the compensated move of line 11 (expanded line 7) (every later move" in err
