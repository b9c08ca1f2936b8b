"""The lines a refusal's text refers to (the G53 that moved an axis, the cycle whose contour is open, the kept cycle,
the tool call, the line after which the controller's state is unknown) named as every note and the refusal's leading
location name a line (compensation/nc_expand.py ``source_line``; issue 47): the source file's line, with the expanded
line where expansion shifts the lines ('8 (expanded line 5)'), ``'k of FILE'`` in a ``--subprograms`` file; a program
read as it is keeps its int lines. The move-extent check's refusal (a likely unit typo) is named at the source line, as
the reader's refusals are.

Each program is written here so that its expansion shifts the lines: a LinuxCNC o-subroutine of 4 source lines (not
written) whose call writes its 2 moves (source line 8 is flat line 5), a Fanuc M98 call writing 2 lines for its 1
(from line 7 on the flat line is the source's plus 1), or a subprogram file read after the main file's lines."""
from functools import partial
from pathlib import Path

import pytest

from compensation.chain_gcode import MAX_SEGMENTS_PER_MOVE, parse_chain_program
from compensation.gcode import AxisWords, parse_program
from compensation.nc_cycles import cycle_pass
from compensation.nc_state import MACHINE, read_work_offsets
from compensation.nc_subfiles import SubprogramFiles
from compensation.turning import parse_lathe_program
from errormap.io import InputError
from errormap.machine import load_machine
from path_files import read_as_compensate

MILL = AxisWords.of(load_machine("mill-xyz"))
SUB = "o100 sub\n  G1 X10 Y10 F100\n  G1 X20\no100 endsub\nG21 G90 G17 G54 G98\nG0 X0 Y0 Z5\no100 call\n"
"""Lines 1-7; the call writes flat lines 3-4, so source line 8 is flat line 5 (lines 1-4 and 7 are not written)."""


def _refusal(read, path: Path, text: str) -> str:
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        read(path)
    return str(exc.value)


@pytest.mark.parametrize("line8, what", [("G53 G0 Y0", "moved Y in machine coordinates (G53)"),
                                         ("G38.2 Z-5 F50", "probed Z (G38.2: it stops where the probe trips)")],
                         ids=["g53", "probe"])
def test_the_line_that_left_an_axis_unknown_is_the_source_line(tmp_path, line8, what):
    """The reader's refusal of a feed move with an axis unknown names the G53 / probe line that made it so (before:
    'line 5', the flat line); the flat program read as it is says 'line 5' as before."""
    read = partial(parse_program, axis_words=MILL, dialect="linuxcnc")
    msg = _refusal(read, tmp_path / "p.ngc", SUB + f"{line8}\nG1 X5 F100\nM2\n")
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line 9, column 4: 'X5': G1 before")
    assert f"; line 8 (expanded line 5) {what}" in msg
    flat = "G21 G90 G17 G54 G98\nG0 X0 Y0 Z5\n  G1 X10 Y10 F100\n  G1 X20\n" + f"{line8}\nG1 X5 F100\nM2\n"
    assert f"; line 5 {what}" in _refusal(read, tmp_path / "flat.ngc", flat)


def test_the_kept_canned_cycle_is_named_by_its_source_line(tmp_path):
    """An incremental move after a kept G81 (its cycle pass reads the flat text of the calls): the cycle's line named
    at the source (before: 'of line 5')."""
    read = partial(parse_program, axis_words=MILL, dialect="linuxcnc", cycles=partial(cycle_pass, mode="keep"))
    msg = _refusal(read, tmp_path / "p.ngc", SUB + "G81 X10 Y10 Z-3 R2 F100\nG80\nG91 G0 X5\nM2\n")
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line 10, column 8: an incremental move after the kept canned cycle "
                          "of line 8 (expanded line 5): the controller")


LATHE_HEAD = "%\nO0300\nG21 G18 G40 G99\nT0101\nG96 S180 M03\nM98 P2000\nG71 U1. R0.5\nG71 P100 Q200 U0.4 W0.1 F0.25\n"
LATHE_TAIL = "G70 P100 Q200\nG00 X150. Z50.\nM30\nO2000\nG00 X120. Z10.\nG00 X110. Z3.\nM99\n%\n"
"""A Fanuc lathe program (tests/test_nc_expand_lines.py LATHE_SOURCE) whose M98 on line 6 writes the subprogram's two
lines: the G71 P Q of source line 8 is flat line 9."""


@pytest.mark.parametrize("contour, at, text", [
    ("G00 X20.\nN100 G01 Z-30. F0.15\nN200 X40.\n", "line 9, column 1",
     "the G71 on line 8 (expanded line 9) names its contour's first block N100"),
    ("N100 G00 X20.\nG01 Z-30. F0.15 M08\nN200 X40.\n", "line 10, column 17",
     "'M08' in the contour blocks N100-N200 of the G71 on line 8 (expanded line 9): only"),
    ("N100 G00 X20.\nG71 U1. R0.5\nN200 X40.\n", "line 10, column 1",
     "'G71' inside the contour blocks N100-N200 of the G71 on line 8 (expanded line 9): a cycle may not be nested")],
                         ids=["not-its-first-block", "word", "nested"])
def test_the_open_contours_cycle_is_named_by_its_source_line(tmp_path, contour, at, text):
    """The contour refusals (compensation/nc_contour.py) name the G71 at the source (before: 'on line 9')."""
    read = partial(parse_lathe_program, machine=load_machine("lathe-xzc"), rapids="keep", block_delete=None,
                   dialect="fanuc", lathe_x="diameter", cycles="keep")
    msg = _refusal(read, tmp_path / "p.nc", LATHE_HEAD + contour + LATHE_TAIL)
    assert msg.startswith(f"{tmp_path / 'p.nc'}: {at}: {text}")


@pytest.mark.parametrize("use, text", [("G0 X[#<_x> + 1]", "#<_x>: the controller's state is not known after line"),
                                       ("G1 @5 ^45 F100", "'@': a LinuxCNC polar coordinate needs the current X Y, "
                                                          "which is not known after line")], ids=["parameter", "polar"])
def test_the_line_the_expander_does_not_follow_is_named_in_its_subprogram_file(tmp_path, use, text):
    """A canned cycle in a ``--subprograms`` file leaves the controller's state unknown to the expander: the refusal of
    a later ``#<_x>`` or polar word names that file's line 2 (before: 'line 7', its place among the lines run, past
    the main file's 5)."""
    (tmp_path / "subs").mkdir()
    sub = tmp_path / "subs" / "drill.ngc"
    sub.write_text("o<drill> sub\nG81 X1 Y1 Z-3 R2 F100\nG80\no<drill> endsub\nM2\n")
    read = partial(parse_program, axis_words=MILL, dialect="linuxcnc", subprograms=SubprogramFiles([tmp_path / "subs"]))
    msg = _refusal(read, tmp_path / "p.ngc", f"G21 G90 G17\nG0 X0 Y0 Z5\no<drill> call\n{use}\nM2\n")
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line 4, column ")
    assert f"{text} 2 of {sub} (a line the reader does not follow)" in msg


def test_the_tool_call_of_an_expanded_program_is_named_at_the_source(tmp_path):
    """A Siemens ISO program with G93 (read by the pre-pass on its flat program, compensation.tcp.flat_prepass) whose
    M98 writes two lines for one: the move after the second tool call without Z is refused at its source line, and
    names the call's (before: 'line 9, ...: the first move after the tool call on line 8', both flat)."""
    read = partial(parse_chain_program, machine=load_machine("mill-xyz"), dialect="siemens-iso")
    msg = _refusal(read, tmp_path / "p.nc",
                   "%\nO0001\nG21 G90 G17 G54\nT1 D1\nG0 X0 Y0 Z50\nM98 P100\nT2 D1\nG0 X10 Y10\nG93 G1 X20 F10\n"
                   "G94\nM30\nO0100\nG0 X5 Y5\nG0 X6 Y6\nM99\n%\n")
    assert msg.startswith(f"{tmp_path / 'p.nc'}: line 8, column 4: the first move after the tool call on line 7 "
                          "(expanded line 8) gives no absolute Z")


def test_the_reader_of_a_pre_passes_flat_program_names_the_source_line(tmp_path):
    """A G93 program with an o-subroutine (the pre-pass expands it, the reader reads its flat text): the G53 line is
    named at the source, as when the reader expands the program itself (before: 'line 5')."""
    read = partial(parse_chain_program, machine=load_machine("mill-xyz"), dialect="linuxcnc")
    msg = _refusal(read, tmp_path / "p.ngc", SUB + "G53 G0 Y0\nG93 G1 X5 F10\nG94\nM2\n")
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line 9, column 8: 'X5': G1 before")
    assert "; line 8 (expanded line 5) moved Y in machine coordinates (G53)" in msg


def test_a_likely_unit_typo_after_a_call_is_refused_at_its_source_line(tmp_path, capsys, monkeypatch):
    """The move-extent check before planning (compensation/pathio.py check_move_extent) names its move as the reader
    does: at the source line (before: 'line 5', the flat line)."""
    from compensation.app.cli import main
    from test_chain_compensate import chain_elements
    el = chain_elements(load_machine("mill-xyz"), 5).save(tmp_path / "el.json")
    monkeypatch.chdir(tmp_path)  # a short path: the CLI shortens a long message in its middle
    Path("p.ngc").write_text(SUB + "G1 X90000 F100\nM2\n")
    assert main(["compensate", "p.ngc", "--machine", "mill-xyz", "--model", str(el), "--method", "exact",
                 "--dialect", "linuxcnc", "--work-offsets", "machine", "--out", "o"]) != 0
    assert "p.ngc: line 8, column 4: 'X90000': a move of 89980 mm, more than the machine's X/Y/Z stroke" in \
        capsys.readouterr().err


def test_a_move_of_too_many_pieces_inside_a_call_is_refused_at_its_source_line(tmp_path):
    """The piece-count limit (compensation/chain_gcode.py ``_check_counts``, checked before any vertex is placed) names
    the move at the source, as the reader does: the subroutine's first move (14.1 mm at 1e-6 mm a piece, the longest)
    is source line 2, flat line 3 (before: 'line 3', the flat line)."""
    read = partial(read_as_compensate, machine=load_machine("mill-xyz"), dialect="linuxcnc", max_segment_mm=1e-6,
                   work_offsets=read_work_offsets(MACHINE))
    msg = _refusal(read, tmp_path / "p.ngc", SUB + "M2\n")
    assert msg.startswith(f"{tmp_path / 'p.ngc'}: line 2 (expanded line 3, called from line 7): the move needs "
                          f"14,142,136 pieces for no piece longer than 1e-06 mm (more than {MAX_SEGMENTS_PER_MOVE:,})")
