"""G-code reading and rewriting (compensation.pathio)."""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from compensation.pathio import parse_gcode, read_path, render_gcode, write_compensated
from errormap.io import InputError
from errormap.machine import load_machine

TOL_MM = 1e-6  # the writer's 6 decimals

PROGRAM = (
    b"%\n"
    b"O1000 (flute test \xe4\xb8\xad)\n"
    b"N10 G21 G90 G17 M3 S24000\r\n"
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
    p.write_bytes(data)
    return p


def test_motion_is_parsed_modally(tmp_path):
    prog = parse_gcode(_write(tmp_path, PROGRAM))
    assert prog.line_numbers.tolist() == [4, 5, 8, 9, 10]
    expected = [[90, 5, 0], [90, 0.3, 0], [90.5, 0.3, 10.5], [91, 0.3, -3], [91.25, 0.35, 0.5]]
    assert np.allclose(prog.positions, expected)


def test_round_trip_keeps_every_non_motion_line_byte_for_byte(tmp_path, machine):
    src = _write(tmp_path, PROGRAM)
    tp = read_path(src, machine)
    new_axes = tp.axes + np.array([0.0123, -0.0045, 0.0678])
    out = write_compensated(tp, tmp_path / "out" / "prog.nc", new_axes, tp.targets_mm)
    assert src.read_bytes() == PROGRAM  # input untouched
    a, b = PROGRAM.split(b"\n"), out.read_bytes().split(b"\n")
    assert len(a) == len(b)
    motion = set(tp.lines - 1)
    for k, (la, lb) in enumerate(zip(a, b)):
        if k not in motion:
            assert la == lb, f"line {k + 1} changed"
    # motion lines keep their other words and comments
    assert b[3].startswith(b"N20 G0 X") and b[3].endswith(b" ; rapid in")
    assert b[7].endswith(b"(cut)")
    back = read_path(out, machine)
    assert np.abs(back.axes - new_axes).max() < TOL_MM
    # rendering the original axes reproduces the positions exactly (numbers reformatted only)
    again = parse_gcode(_write(tmp_path, render_gcode(tp.source, tp.axes).encode("latin-1"), "again.nc"))
    assert np.abs(again.positions - tp.axes).max() < TOL_MM


def test_refuses_to_overwrite_the_input(tmp_path, machine):
    src = _write(tmp_path, PROGRAM)
    tp = read_path(src, machine)
    with pytest.raises(InputError, match="overwrite"):
        write_compensated(tp, src, tp.axes, tp.targets_mm)
    assert src.read_bytes() == PROGRAM


@pytest.mark.parametrize("body, line, what", [
    (b"G1 X1 Z2 A3\nG1 X#1\n", 2, "plain number"),
    (b"G1 X1 Z2 A3\nG2 X2 Z2 A3 I1\n", 2, "G2"),
    (b"G1 X1 Z2 A3\nG91\nX1\n", 3, "G91"),
    (b"G20 G1 X1 Z2 A3\n", 1, "G20"),
    (b"G1 X1 Z2 A3\nG92 X0\n", 2, "G92"),
    (b"X1 Z2 A3\n", 1, "no G0/G1"),
    (b"G1 X1\n", 1, "Z, A"),
    (b"G1 X1 X2 Z2 A3\n", 1, "repeated"),
    (b"G0 G1 X1 Z2 A3\n", 1, "two motion"),
    (b"(ok)\nG1 X1 Z2 A3 (open\n", 2, "unclosed"),
    (b"G1 X1 Z2 A3\nG Z4\n", 2, "'G' word"),
])
def test_bad_lines_are_named(tmp_path, body, line, what):
    with pytest.raises(InputError, match=rf"prog\.nc: line {line}: .*{what}"):
        parse_gcode(_write(tmp_path, body))


def test_no_motion_is_refused(tmp_path):
    with pytest.raises(InputError, match="no G0/G1 motion"):
        parse_gcode(_write(tmp_path, b"%\nM30\n%\n"))


GCODE_ALPHABET = st.sampled_from(list("GXZAYFNMST0123456789.-+ ();%/#[]\r\t") + ["\n", "G1", "G0", " X", " Z", " A", "\xe9"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.lists(GCODE_ALPHABET, max_size=80).map("".join), prefix=st.booleans())
def test_fuzzed_gcode_parses_or_raises_input_error(tmp_path, machine, text, prefix):
    data = ("G1 X1 Z2 A3\n" if prefix else "") + text
    p = _write(tmp_path, data.encode("latin-1"), "fuzz.nc")
    try:
        tp = read_path(p, machine)
    except InputError as exc:
        assert "fuzz.nc" in str(exc)
        return
    assert tp.axes.shape == (len(tp.lines), 3) and np.all(np.isfinite(tp.axes))
    out = render_gcode(tp.source, tp.axes)
    # non-motion lines pass through unchanged
    motion = set(tp.lines - 1)
    src_lines = data.split("\n")
    for k, line in enumerate(out.split("\n")):
        if k not in motion:
            assert line == src_lines[k]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=200))
def test_arbitrary_bytes_parse_or_raise_input_error(tmp_path, machine, data):
    p = _write(tmp_path, b"G21 G90 G1 X1 Z2 A3\n" + data, "bytes.nc")
    try:
        tp = read_path(p, machine)
    except InputError as exc:
        assert "bytes.nc" in str(exc)
        return
    assert len(tp) >= 1 and np.all(np.isfinite(tp.targets_mm))
