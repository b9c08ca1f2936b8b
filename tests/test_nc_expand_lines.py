"""One line-number convention for the summary's notes about a program whose subprograms and parameters were
expanded (compensation/nc_expand.py ``source_line``; issue 47): every note names the source file's line, with the
expanded (flat) line and the call sites where the lines shift; a program read as it is keeps its int lines.

The program is written here (LinuxCNC O-codes, "O Codes: Subroutines", and numbered parameters): a subroutine holding
a G53 move, called twice, then G92, G38.2, G43.1 and G41.1 lines after it, so the flat program's line numbers fall
behind the source's."""
import json
from pathlib import Path

import numpy as np
import pytest

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


LATHE_SOURCE = """%
O0300
G21 G18 G40 G99
T0101
G96 S180 M03
M98 P2000
G71 U1. R0.5
G71 P100 Q200 U0.4 W0.1 F0.25
N100 G00 X20.
G01 Z-30. F0.15
N200 X40.
G70 P100 Q200
G00 X64. Z-62.
G75 R0.5
G75 X52. Z-62. P2000 F0.08
G00 X150. Z50.
M30
O2000
G00 X120. Z10.
G00 X110. Z3.
M99
%
"""
"""A Fanuc lathe program (0i-TF formats: two-block G71 type I, G70, a one-column G75) whose call on line 6 writes the
subprogram's two lines in its place (the call line and the program numbers are not written): from line 7 on the
flat program's line is the source's plus one, and --expand-cycles writes the G70 as its contour's 3 lines and a G0
(the G75 R0.5 after it at flat line 14 + 3 = 17 + 1)."""


def test_lathe_cycle_notes_name_the_source_line_whether_kept_or_expanded(tmp_path):
    """The lathe cycles' notes (the summary's ``lathe_cycles``: compensation/nc_notes.py) follow the same convention:
    kept (noted while reading, on the flat lines) and written as moves (noted by each expansion step) alike."""
    from compensation.nc_notes import cycle_notes
    from compensation.turning import parse_lathe_program
    (tmp_path / "p.nc").write_text(LATHE_SOURCE)

    def heads(cycles):
        prog, _ = parse_lathe_program(tmp_path / "p.nc", load_machine("lathe-xzc"), "keep", None, "fanuc",
                                      "diameter", cycles=cycles)
        return [n.split(" (stock")[0].split(" written as")[0].split(": roughing")[0] for n in cycle_notes(prog)]
    contour = "(lines 9 (expanded line 10) to 11 (expanded line 12))"
    assert heads("keep") == ["line 8 (expanded line 9): G71 P100 Q200",
                             f"line 12 (expanded line 13): G70 P100 Q200: finishing pass: exactly the compensated "
                             f"contour {contour}"]
    assert heads("expand") == ["line 8 (expanded line 9): G71 P100 Q200",
                               f"line 12 (expanded line 13): G70 P100 Q200 expanded: the contour's blocks {contour}",
                               "line 15 (expanded line 19): G75 (diameter grooving cycle) expanded: 1 column(s), 3 "
                               "feed(s),"]


def test_a_kept_cycles_tilt_in_a_subprogram_file_is_keyed_by_that_file_line(tmp_path, monkeypatch):
    """``cycles.tilt_um`` (compensation/app/workflows/compensate_report.py) of a G81 kept in a ``--subprograms``
    file called twice: one key, the file's line 2 named as every note names it, its largest tilt over both calls."""
    from compensation.app.cli import main
    from test_chain_compensate import chain_elements
    el = chain_elements(load_machine("mill-xyz"), 5).save(tmp_path / "el.json")
    (tmp_path / "off.csv").write_text("system,x_mm,y_mm,z_mm\nG54,300,200,-300\n")
    (tmp_path / "subs").mkdir()
    (tmp_path / "subs" / "hole.ngc").write_text("o<hole> sub\nG81 X#1 Y#2 Z-3 R2 F100\nG80\no<hole> endsub\nM2\n")
    monkeypatch.chdir(tmp_path)
    Path("p.ngc").write_text("G21 G90 G17 G54 G98\nG0 X0 Y0 Z5\no<hole> call [10] [10]\no<hole> call [40] [25]\n"
                             "G0 Z20\nM2\n")
    assert main(["compensate", "p.ngc", "--machine", "mill-xyz", "--model", str(el), "--method", "exact",
                 "--dialect", "linuxcnc", "--work-offsets", "off.csv", "--subprograms", "subs", "--out", "o"]) == 0
    cyc = json.loads(Path("o/compensate_summary.json").read_text())["files"][0]["cycles"]
    name = "2 of subs/hole.ngc"  # the file as read, its folder as --subprograms gave it (before: '8', past p.ngc's 6)
    assert cyc["holes"] == 2 and list(cyc["tilt_um"]) == [name] and cyc["tilt_max_line"] == name


def test_the_expanders_refusal_names_the_call_sites_as_the_notes_do(tmp_path):
    """A refusal inside a subprogram file called from another one: its file and line, then each call site as the notes
    name it, innermost first ('k of FILE' in a subprogram file, the main file's line as an int)."""
    from compensation.nc_expand import expand_program
    from compensation.nc_subfiles import SubprogramFiles
    from errormap.io import InputError
    (tmp_path / "outer.ngc").write_text("o<outer> sub\nG0 X1\no<inner> call\no<outer> endsub\nM2\n")
    (tmp_path / "inner.ngc").write_text("o<inner> sub\nG0 X#7 Y0\no<inner> endsub\nM2\n")
    outer = SubprogramFiles([tmp_path])
    with pytest.raises(InputError) as exc:
        expand_program("G21 G90\nG0 X0 Y0 Z5\no<outer> call\nM2\n", "m.ngc", "linuxcnc", None, outer)
    inner, called = (str(Path(tmp_path / f).resolve()) for f in ("inner.ngc", "outer.ngc"))
    assert str(exc.value).startswith(f"{inner}: line 2, column 5 (called from line 3 of {called}) "
                                     "(called from line 3): #7 is not passed")


def test_a_dynamic_offset_is_named_by_its_source_line_in_a_refusal():
    """The G43.1 / G41.1 offsets a program sets are tools of its own (compensation.nc_state._Controller), named in a
    refusal by the line that set them (as every refusal names a line), never by an internal key. No G10 changes them
    today, so this drives the controller's check directly."""
    from compensation.nc_state import _Controller
    from errormap.io import InputError
    c = _Controller("p.ngc", MILL.words, None, None)
    c.name = lambda k: f"{k - 2} (expanded line {k})"
    c.apply((15, 1, "tool-dynamic", {"Z": 10.0}, "G43.1 Z10"))
    c.apply((17, 1, "cutter-dynamic", 2.0, "G41.1 D4"))
    del c.tooltab[c.tool]
    with pytest.raises(InputError, match=r"^w: the length of the active tool set by the G43\.1 on line 14 \(expanded "
                                         r"line 16\) is no longer known$"):
        c.check_active("w")
    c.tool, c.radii[c.cutter] = None, np.nan
    with pytest.raises(InputError, match=r"^w: the radius of the active cutter compensation set by the G41\.1/G42\.1 "
                                         r"on line 16 \(expanded line 18\) is no longer known$"):
        c.check_active("w")


def test_the_g80_reading_in_a_subprogram_file_names_that_files_line(tmp_path):
    """A program of no dialect word whose ``G80 G0`` line (read as the controllers that run it read it, the header
    and the evidence say where) is in a ``--subprograms`` file: named there (line 5 of the file), not by the line's
    place among all the lines run (13: the main file's 8, then the file's 5)."""
    from compensation.nc_subfiles import SubprogramFiles
    (tmp_path / "subs").mkdir()
    (tmp_path / "main.nc").write_text("%\nO0047\nG21 G90 G17 G54\nG0 X20. Y20. Z5.\nM98 P9100\nG0 X60. Y40.\nM30\n%\n")
    sub = tmp_path / "subs" / "slot.nc"
    sub.write_text("%\nO9100 (SLOT)\nG91 G1 Z-7. F200.\nX15. Y5.\nG80 G0 Z7.\nG90\nM99\n%\n")
    prog = parse_program(tmp_path / "main.nc", axis_words=MILL, dialect="auto",
                         subprograms=SubprogramFiles([tmp_path / "subs"]))
    assert prog.g80_line == f"5 of {sub}"
    assert f"first at line 5 of {sub})" in prog.dialect_evidence
    assert any(f"first at line 5 of {sub})" in note for note in prog.notes())
