"""LinuxCNC's modal-state save / restore M70-M73 (compensation/nc_modal.py), on programs written here from
LinuxCNC's G-code manual ("M70 Save Modal State" ... "M73 Save and Autorestore Modal State"): the flat program
gets the restored modal words as ordinary lines, so the reader finds the points the controller cuts; what the
program does not determine is refused with line and column."""
import numpy as np
import pytest

from compensation.gcode import AxisWords, parse_program
from compensation.nc_expand import expand_program
from errormap.io import InputError
from errormap.machine import load_machine

MILL = AxisWords.of(load_machine("mill-xyz"))
MM_PER_INCH = 25.4

M70_M72 = """(M70 / M72 around a call of a subroutine that changes units and distance mode)
o<inchsub> sub
G20 G91
F5
G1 X1 Y0.5
o<inchsub> endsub
G21 G90 G17
F200
G54
G0 X10 Y10 Z5
M70
o<inchsub> call
M72
G1 X20 Y20
M2
"""
"""After the call (G20 G91: one incremental inch-move), M72 puts back G21 G90 F200: X20 Y20 is absolute mm."""

M73 = """(M73 in the subroutine: restored when it returns, at endsub and at return)
o<sub> sub
M73
G91 G20
G1 X1 F10
o10 if [#1 GT 0]
o<sub> return
o10 endif
G1 Y1
o<sub> endsub
G21 G90 F300
G0 X0 Y0 Z0
o<sub> call [0]
G1 X5
o<sub> call [1]
G1 Y5
M2
"""


def _ends(text, tmp_path, name="p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    prog = parse_program(p, axis_words=MILL, dialect="linuxcnc")
    return np.array([m.end for m in prog.moves]), prog


def test_m72_restores_units_distance_and_feed(tmp_path):
    e = expand_program(M70_M72, "m.ngc", "linuxcnc")
    lines = e.text.splitlines()
    restore = [ln for ln, (src, verbatim, _) in zip(lines, e.origin) if src == 13 and not verbatim and ln.strip()]
    assert restore == ["G21", "G90", "F200"]  # only the groups that differ, units first
    assert not any(ln.strip() in ("M70", "M72") for ln in lines)  # the words are blanked (the comment keeps its text)
    ends, _ = _ends(M70_M72, tmp_path)
    # by hand: G0 X10 Y10 Z5; in the call one inch incremental move (+25.4, +12.7); then absolute X20 Y20 in mm
    want = np.array([[10.0, 10.0, 5.0], [10.0 + MM_PER_INCH, 10.0 + 0.5 * MM_PER_INCH, 5.0], [20.0, 20.0, 5.0]])
    assert np.allclose(ends, want, atol=1e-12)


def test_m73_restores_at_endsub_and_at_return(tmp_path):
    ends, _ = _ends(M73, tmp_path)
    # call [0]: X+1in, Y+1in (incremental), endsub restores G21 G90 -> G1 X5 absolute mm;
    # call [1]: X+1in then return restores -> G1 Y5 absolute mm
    x1 = MM_PER_INCH
    want = np.array([[0, 0, 0], [x1, 0, 0], [x1, x1, 0], [5, x1, 0], [5 + x1, x1, 0], [5 + x1, 5, 0]], float)
    assert np.allclose(ends, want, atol=1e-12)


@pytest.mark.parametrize("text,fragment", [
    ("G21 G90\nG0 X0 Y0 Z0\nM72\nG1 X1 F100\nM2\n", "line 3, column 1: 'M72' with no state saved"),
    ("G21 G90\nG0 X0 Y0 Z0\nM70 G91\nG1 X1 F100\nM2\n", "line 3, column 1: 'M70' (modal state save/restore) with "
     "other words"),
    ("G21\nG0 X0 Y0 Z0\nM70\nG91\nM72\nG1 X1 F100\nM2\n", "line 5, column 1: restoring the modal state (M72/M73) "
     "would set the distance back to the controller's start-up value"),
    ("G21 G90 G40\nG0 X0 Y0 Z0\nM70\nG41 D1\nG1 X1 F100\nM72\nG1 X2\nM2\n", "line 6, column 1: restoring the modal "
     "state (M72/M73) would change the cutter from 'G41 D1' to 'G40'"),
    ("G21 G90\nT1 M6\nG43 H1\nG0 X0 Y0 Z0\nM70\nT2 M6\nG43 H2\nM72\nG1 X1 F100\nM2\n", "line 8, column 1: "
     "restoring the modal state (M72/M73) after a tool change"),
])
def test_what_the_program_does_not_determine_is_refused(tmp_path, text, fragment):
    p = tmp_path / "bad.ngc"
    p.write_text(text)
    with pytest.raises(InputError, match="bad.ngc") as e:
        parse_program(p, axis_words=MILL, dialect="linuxcnc")
    assert fragment in str(e.value), str(e.value)


def test_m70_outside_linuxcnc_is_not_read_as_a_save(tmp_path):
    p = tmp_path / "f.nc"
    p.write_text("G21 G90\nG0 X0 Y0 Z0\nM70\nG1 X1 F100\nM30\n")
    with pytest.raises(InputError, match="M70"):
        parse_program(p, axis_words=MILL, dialect="fanuc")
