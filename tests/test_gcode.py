"""G-code reading and rewriting (compensation.gcode, compensation.chain_gcode)."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.gcode import MM_PER_INCH, AxisWords, move_points, parse_program
from compensation.nc_state import MACHINE, read_work_offsets
from compensation.app.validate import UsageError
from compensation.app.workflows.compensate import plan_outputs
from errormap.io import InputError
from errormap.machine import load_machine
from path_files import read_as_compensate, render_gcode, write_compensated

MCS = read_work_offsets(MACHINE)
"""The G-code programs here are written in machine coordinates (the grinder's axes): read with
--work-offsets machine (a program is never read at an assumed zero)."""

TOL_MM = 1e-6        # the writer's 6 decimals (mm)
TOL_INCH_MM = 2.6e-6  # 7 decimals in inch: 0.5e-7 in = 1.3 nm; two roundings
TOL_DEG = 1e-6

PROGRAM = (
    b"%\n"
    b"O1000 (flute test \xe4\xb8\xad)\n"
    b"N10 G21 G90 G18 M3 S24000\r\n"
    b"N20 G0 X90 Z5 A0 ; rapid in\n"
    b"N30 G1 Z0.3 F100\n"
    b"\n"
    b"  (a comment with X99 Z99 A99 inside)\n"
    b"N40 X90.5 A10.5 (cut)\n"
    b"N50 x91. a-3\n"
    b"/N55 G1 X+91.25 Z .35 A.5\n"
    b"N60 M5 ; X1 in a comment\n"
    b"M30\n"
    b"%"
)


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def _write(tmp_path, data, name="prog.nc"):
    p = tmp_path / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode("latin-1"))
    return p


def test_motion_is_parsed_modally(tmp_path, machine):
    tp = read_as_compensate(_write(tmp_path, PROGRAM), machine, rapids="compensate", block_delete="off", work_offsets=MCS)
    assert tp.lines.tolist() == [4, 5, 8, 9, 10]
    expected = [[90, 5, 0], [90, 0.3, 0], [90.5, 0.3, 10.5], [91, 0.3, -3], [91.25, 0.35, 0.5]]
    assert np.allclose(tp.axes, expected)
    # rapids kept (the default): the G0 line is not a compensated point
    kept = read_as_compensate(_write(tmp_path, PROGRAM), machine, block_delete="off", work_offsets=MCS)
    assert kept.lines.tolist() == [5, 8, 9, 10]


def test_block_delete_is_an_explicit_choice(tmp_path, machine):
    src = _write(tmp_path, PROGRAM)
    with pytest.raises(InputError, match=r"prog\.nc: line 10, column 1: block delete"):
        read_as_compensate(src, machine, work_offsets=MCS)
    on = read_as_compensate(src, machine, block_delete="on", work_offsets=MCS)  # the controller skips line 10
    assert on.lines.tolist() == [5, 8, 9]
    # a '/' line that neither moves nor changes modal state passes under the default
    ok = read_as_compensate(_write(tmp_path, b"G21 G90 G1 X1 Z2 A3\n/M8 (coolant)\n", "bd.nc"), machine, work_offsets=MCS)
    assert len(ok) == 1


def test_round_trip_keeps_every_other_line_byte_for_byte(tmp_path, machine):
    src = _write(tmp_path, PROGRAM)
    tp = read_as_compensate(src, machine, block_delete="off", work_offsets=MCS)  # as compensate reads it
    new_axes = tp.axes + np.array([0.0123, -0.0045, 0.0678])
    out = write_compensated(tp, tmp_path / "out" / "prog.nc", machine, new_axes)
    assert src.read_bytes() == PROGRAM  # input untouched
    a, b = PROGRAM.split(b"\n"), out.read_bytes().split(b"\n")
    assert len(a) == len(b)
    motion = set(tp.lines - 1)
    for k, (la, lb) in enumerate(zip(a, b)):
        if k not in motion:
            assert la == lb, f"line {k + 1} changed"
    assert b[4] == b"N30 G1 Z0.295500 X90.012300 A0.067800 F100"
    assert b[7] == b"N40 X90.512300 A10.567800 Z0.295500 (cut)"
    assert b[9].startswith(b"/N55 G1 X")
    back = read_as_compensate(out, machine, block_delete="off", work_offsets=MCS)
    assert np.abs(back.axes - new_axes).max() < TOL_MM


def test_refuses_to_overwrite_the_input(tmp_path, machine):
    src = _write(tmp_path, PROGRAM)
    with pytest.raises(UsageError, match="would overwrite the input"):   # compensate's output plan
        plan_outputs([src], src.parent)
    assert src.read_bytes() == PROGRAM


@pytest.mark.parametrize("body, line, col, what", [
    (b"G1 X1 Z2 A3\nG1 X#1\n", 2, 5, "#1 is not set by the program"),  # parameters: compensation/nc_expand.py
    (b"G1 X1 Z2 A3\nG1 X[1+2\n", 2, 5, "'.' without its '.'"),
    (b"G1 X1 Z2 A3\nG17 G2 X2 Z2 A3 I1\n", 2, 8, "G17 plane"),
    (b"G1 X1 Z2 A3\nG92 X0\n", 2, 1, "'G92'"),
    (b"X1 Z2 A3\n", 1, 1, "no motion mode"),
    (b"G1 X1\n", 1, 4, "Z, A"),
    (b"G1 X1 X2 Z2 A3\n", 1, 7, "repeated 'X'"),
    (b"G0 G1 X1 Z2 A3\n", 1, 4, "same modal group"),
    (b"(ok)\nG1 X1 Z2 A3 (open\n", 2, 13, "unclosed"),
    (b"G1 X1 Z2 A3\nG Z4\n", 2, 1, "'G' word without"),
    (b"G1 X1e2 Z2 A3\n", 1, 4, "exponent"),
    (b"G1 X1 Z2 A3\nG1 U1.0\n", 2, 4, "'U1.0'"),
    (b"G65 P9000 A1 X2 Z3\n", 1, 5, "G65 P9000: program O9000 is not in this file"),
    (b"G1 X1 Z2 A3\nG1 X2 @5\n", 2, 7, "'@': a LinuxCNC polar coordinate"),
    (b"G21\nG91 G1 X1 Z1 A1\n", 2, 8, "incremental 'X1' before X is known"),
    (b"G1 X1 Z2 A3\nG4 X1.5\n", 2, 4, "dwell"),
    (b"G1 X1 Z2 A3 P2\n", 1, 13, "'P2' outside G4/G64"),
    (b"G1 X1 Z2 A3\nG1 X2 I1\n", 2, 7, "arc words need G2/G3"),
    (b"G1 X1 Z2 A3\nG18 G2 X2 Z2 I5 K0\n", 2, 8, "radii differ"),
    (b"G1 X1 Z2 A3\nG18 G2 X9 Z2 R1\n", 2, 14, "smaller than half the chord"),
])
def test_bad_lines_are_named(tmp_path, machine, body, line, col, what):
    with pytest.raises(InputError, match=rf"prog\.nc: line {line}, column {col}: .*{what}"):
        read_as_compensate(_write(tmp_path, body), machine, work_offsets=MCS)


def test_no_motion_is_refused(tmp_path, machine):
    with pytest.raises(InputError, match="no G0/G1/G2/G3 motion"):
        read_as_compensate(_write(tmp_path, b"%\nM30\n%\n"), machine, work_offsets=MCS)


def test_numbers_are_read_as_rs274(tmp_path, machine):
    tp = read_as_compensate(_write(tmp_path, b"G21 G90 G1 X1 0 Z 2. 5 A-1 2.5\n"), machine, work_offsets=MCS)
    assert tp.axes.tolist() == [[10.0, 2.5, -12.5]]
    txt, groups = render_gcode(tp, tp.axes)
    assert groups[0] == ["G21 G90 G1 X10.000000 Z2.500000 A-12.500000\n"]


def _arc_program(tmp_path, lines, name="arc.nc"):
    return read_as_compensate(_write(tmp_path, "G21 G90 G18 G1 X10 Z5 A0 F100\n" + lines, name), machine=load_machine(),
                     arc_tolerance_um=0.5, work_offsets=MCS)


@pytest.mark.parametrize("arc, centre_xz, ccw", [
    ("G2 X12 Z7 I2 K0\n", (12.0, 5.0), False),     # I K incremental centre: clockwise is the long way
    ("G3 X12 Z7 I0 K2\n", (10.0, 7.0), True),
    ("G2 X12 Z7 R2\n", (10.0, 7.0), False),        # R form: the short arc
    ("G90.1 G3 X12 Z7 I10 K7\n", (10.0, 7.0), True),  # absolute centre
])
def test_arcs_in_g18_follow_the_circle(tmp_path, arc, centre_xz, ccw):
    tp = _arc_program(tmp_path, arc)
    pts = tp.axes[1:]
    r = np.hypot(pts[:, 0] - centre_xz[0], pts[:, 1] - centre_xz[1])
    assert np.abs(r - 2.0).max() < 1e-9 and np.allclose(pts[-1], [12, 7, 0])
    # G3 is counter-clockwise seen from +Y: in (Z, X) coordinates the angle increases
    ang = np.unwrap(np.arctan2(pts[:, 0] - centre_xz[0], pts[:, 1] - centre_xz[1]))
    assert np.all(np.diff(ang) > 0) if ccw else np.all(np.diff(ang) < 0)
    # chords within the 0.5 um tolerance: sagitta r(1 - cos(step/2))
    step = abs(ang[1] - ang[0])
    assert 2.0 * (1 - math.cos(step / 2)) <= 0.5e-3 + 1e-12


def test_full_circle_and_helical_a(tmp_path):
    tp = _arc_program(tmp_path, "G3 K2 X10 Z5 A90\n")
    move = [m for m in tp.source.program.moves if m.compensate][1]
    assert move.arc["sweep"] == pytest.approx(2 * math.pi)
    mid = move_points(move, [0.5])[0]
    assert np.allclose(mid, [10.0, 9.0, 45.0])


def test_incremental_and_inch_are_written_back_in_their_own_mode(tmp_path, machine):
    src = _write(tmp_path, "G20 G90 G1 X4 Z0.1 A0 F10\nG91 X0.5 A10\nZ0.01\nG90 G21 X120 (mm again)\n")
    tp = read_as_compensate(src, machine, work_offsets=MCS)
    assert np.allclose(tp.axes, [[4 * MM_PER_INCH, 0.1 * MM_PER_INCH, 0], [4.5 * MM_PER_INCH, 0.1 * MM_PER_INCH, 10],
                                 [4.5 * MM_PER_INCH, 0.11 * MM_PER_INCH, 10], [120, 0.11 * MM_PER_INCH, 10]])
    comp = tp.axes + np.array([0.0011, -0.0007, 0.003])
    text, groups = render_gcode(tp, comp)
    assert groups[1][0].startswith("G91 X0.5000000 A10.000000 Z0.0000000")  # equal offsets: same increments
    assert groups[3][0].startswith("G90 G21 X120.001100 ")
    back = read_as_compensate(_write(tmp_path, text, "back.nc"), machine, work_offsets=MCS)
    assert np.abs(back.axes[:, :2] - comp[:, :2]).max() < TOL_INCH_MM
    assert np.abs(back.axes[:, 2] - comp[:, 2]).max() < TOL_DEG


def test_incremental_rounding_does_not_accumulate(tmp_path, machine):
    n = 3000
    body = "G21 G90 G1 X10 Z1 A0 F100\nG91\n" + "X0.001 A0.1\n" * n
    tp = read_as_compensate(_write(tmp_path, body), machine, work_offsets=MCS)
    rng = np.random.default_rng(3)
    comp = tp.axes + rng.uniform(-3e-4, 3e-4, tp.axes.shape)  # offsets that do not round evenly
    text, _ = render_gcode(tp, comp)
    back = read_as_compensate(_write(tmp_path, text, "back.nc"), machine, work_offsets=MCS)
    # each point within one rounding of its own value: no drift over 3,000 increments
    assert np.abs(back.axes[:, :2] - comp[:, :2]).max() <= 0.5e-6 + 1e-12
    assert np.abs(back.axes[:, 2] - comp[:, 2]).max() <= 0.5e-6 + 1e-12


def test_long_moves_are_split_and_rejoin_the_line(tmp_path, machine):
    src = _write(tmp_path, "G21 G90 G1 X10 Z1 A0 F100\nN20 G1 X30 (long)\n")
    tp = read_as_compensate(src, machine, max_segment_mm=2.0, work_offsets=MCS)
    assert len(tp) == 1 + 10 and np.allclose(tp.axes[1:, 0], np.linspace(12, 30, 10))
    text, groups = render_gcode(tp, tp.axes)
    assert groups[1][0] == "N20 G1 X12.000000 Z1.000000 A0.000000 (long)\n"
    assert groups[1][1:] == [f"X{x:.6f} Z1.000000 A0.000000\n" for x in np.linspace(14, 30, 9)]


GCODE_ALPHABET = st.sampled_from(list("GXZAYFNMST0123456789.-+ ();%/#[]\r\t") + ["\n", "G1", "G0", " X", " Z", " A", "\xe9"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.lists(GCODE_ALPHABET, max_size=80).map("".join), prefix=st.booleans())
def test_fuzzed_gcode_parses_or_raises_input_error(tmp_path, machine, text, prefix):
    data = ("G1 X1 Z2 A3\n" if prefix else "") + text
    p = _write(tmp_path, data.encode("latin-1"), "fuzz.nc")
    try:
        tp = read_as_compensate(p, machine, work_offsets=MCS)
    except InputError as exc:
        assert "fuzz.nc" in str(exc)
        return
    assert tp.axes.shape == (len(tp.lines), 3) and np.all(np.isfinite(tp.axes))
    _, groups = render_gcode(tp, tp.axes)
    motion = set(tp.lines - 1)
    for k, line in enumerate(tp.source.program.lines):
        if k not in motion:
            assert groups[k] == [line]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=200))
def test_arbitrary_bytes_parse_or_raise_input_error(tmp_path, machine, data):
    p = _write(tmp_path, b"G21 G90 G1 X1 Z2 A3\n" + data, "bytes.nc")
    try:
        tp = read_as_compensate(p, machine, work_offsets=MCS)
    except InputError as exc:
        assert "bytes.nc" in str(exc)
        return
    assert len(tp) >= 1 and np.all(np.isfinite(tp.axes))


def test_parse_program_options_are_checked(tmp_path):
    src = _write(tmp_path, b"G1 X1 Z2 A3\n")
    with pytest.raises(ValueError, match="rapids"):
        parse_program(src, rapids="maybe")
    with pytest.raises(ValueError, match="block_delete"):
        parse_program(src, block_delete="yes")


def test_every_line_has_one_class(tmp_path):
    """The per-line contract a faster reader must keep: pass / state / move / skipped."""
    prog = parse_program(_write(tmp_path, PROGRAM), block_delete="on")
    assert prog.classes == ["pass", "pass", "state", "move", "move", "pass", "pass", "move", "move", "skipped",
                            "pass", "pass", "pass"]
    assert [m.index + 1 for m in prog.moves if not m.compensate] == [4]  # the kept rapid


def test_header_goes_after_tape_start_and_program_number(tmp_path, machine):
    tp = read_as_compensate(_write(tmp_path, b"%\nO1000 (NAME)\nG21 G90 G1 X1 Z2 A3\nM30\n%\n"), machine, work_offsets=MCS)
    text, groups = render_gcode(tp, tp.axes, header=["note (x)"])
    assert text.splitlines()[:4] == ["%", "O1000 (NAME)", "(note [x])", "G21 G90 G1 X1.000000 Z2.000000 A3.000000"]


def test_linuxcnc_polar_words_are_refused_by_name(tmp_path):
    """LinuxCNC's polar coordinates (``@`` distance, ``^`` angle) on a canned cycle's modal repeat are not read (the
    reader does not follow the position after a cycle line; on G0-G3 and cycle lines they are:
    tests/test_polar_words.py, tests/test_nc_offset_words.py): refused naming the word."""
    p = tmp_path / "polar.ngc"
    p.write_text("G20 G17 G90\nG0 X1.5 Y0 Z1\nG81 X1.5 Y0 R.1 Z-.5 F10\n^60\nM2\n")
    with pytest.raises(InputError) as e:
        parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect="linuxcnc")
    assert "polar.ngc: line 4, column 1: '^': a LinuxCNC polar coordinate needs the current X Y" in str(e.value)


def test_a_folder_given_as_the_program_is_named_as_a_folder(tmp_path):
    """A folder where a program is expected is refused as what it is, not as a missing file."""
    with pytest.raises(InputError, match="is a folder; expected a regular file"):
        parse_program(tmp_path)
