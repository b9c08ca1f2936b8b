"""The remaining words real programs use (compensation/gcode_state.py, nc_state.py, dialects.py, nc_cycles.py),
each read exactly by its controller's manual or refused by line and column with the reason: ``G10 L20``
(LinuxCNC/grbl: a work offset set from the current position; Fanuc: ``G54.1 Pn``; Haas: ``G154 Pn``), ``G10
L10/L11`` (LinuxCNC: a tool length from the current Z; Fanuc/Haas: geometry and wear), Haas ``L12/L13``
(diameter), Haas ``G154 P1..P99`` / ``G110..G129`` (from the program or an offsets file), LinuxCNC
``M62..M68`` (passed through), Siemens native-mode calls (refused), ``G76/G87/G88`` by dialect, LinuxCNC's
bare ``G43``/``G41`` (the tool ``M6`` loaded), centre-format full circles without axis words, LinuxCNC's own arc
radius tolerance. The expected frames are worked by hand from the manuals' definitions in each test (machine =
program + offset + tool length on Z); three programs are compensated end to end and checked by the TRUE machine
(tests/program_checks.py)."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_cycles import expand_cycles
from compensation.nc_state import program_frames, read_tool_table, read_work_offsets
from errormap.io import InputError
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from program_checks import TOL_POINT_UM, true_point_errors_um

HERE = Path(__file__).resolve().parent
DATA = HERE / "data" / "words"
OFFSETS = HERE / "data" / "controller" / "offsets.csv"  # G54 0 0 0, G55 200 100 -150, G54.1P3, G59.1
TOOLS = HERE / "data" / "controller" / "tools.csv"  # 1: 150 mm r5, 2: 100 mm r3, 3: 0
TOL_MM = 1e-9
"""Offsets and lengths are sums of a few numbers of up to 6 digits: exact to round-off."""


@pytest.fixture(scope="module")
def ax():
    return AxisWords.of(load_machine("mill-xyz"))


def _frames(tmp_path, ax, text, dialect=None, offsets=OFFSETS, tools=TOOLS):
    p = tmp_path / "p.nc"
    p.write_text(text, encoding="latin-1")
    prog = parse_program(p, axis_words=ax, dialect=dialect, fast=False)
    fr = program_frames(prog, read_work_offsets(offsets) if offsets else None,
                        read_tool_table(tools) if tools else None)
    moves = [m for m in prog.moves if m.compensate]
    off, tool = fr.at([m.index for m in moves])
    return prog, moves, off, tool


def _refused(tmp_path, ax, text, dialect=None, offsets=OFFSETS, tools=TOOLS):
    with pytest.raises(InputError) as exc:
        _frames(tmp_path, ax, text, dialect, offsets, tools)
    return str(exc.value)


# ---------------------------------------------------------------------------- G10 L20
def test_linuxcnc_l20_sets_the_offset_so_the_current_position_reads_the_values(tmp_path, ax):
    """LinuxCNC G-code reference, G10 L20: as L2, but the offset is calculated so that the current
    coordinates become the given values. At G55 (200, 100, -150) + tool 1 (150 mm), program (10, 10, -20):
    machine (210, 110, -20); 'G10 L20 P2 X0 Y0' -> G55 X 210, Y 110 (Z unchanged); the next move is read in
    the new frame without a new absolute position (the current position reads X0 Y0)."""
    text = ("G21 G90 G55 G43 H1\nG0 X10 Y10\nG0 Z-20\nG10 L20 P2 X0 Y0\nG91 G1 X5 F100\nG90 X7 Y3 Z-30\n"
            "G0 X7 Y3 Z-30\nG10 L20 P1 Z2\nG54\nG0 X0 Y0 Z0\nG1 X1\nM2\n")  # the kept G0: see the next test
    _, moves, off, tool = _frames(tmp_path, ax, text, "linuxcnc")
    assert moves[0].end[0] == 5.0 and moves[0].start[0] == 0.0  # incremental from the position that reads X0
    assert np.abs(off[0] - [210, 110, -150]).max() < TOL_MM and np.abs(off[1] - [210, 110, -150]).max() < TOL_MM
    # G10 L20 P1 Z2 at program Z -30 in G55 with tool 1: machine Z = -30 - 150 + 150 = -30 -> G54 Z = -30 - 150 - 2
    # (the tool length is the same on both sides: it cancels)
    assert np.abs(off[-1] - [0, 0, -30 - 150 - 2]).max() < TOL_MM and tool[-1] == 150.0


def test_an_offset_set_from_the_position_after_a_compensated_move_is_refused(tmp_path, ax):
    """Running the written program, G10 L20 takes the offset from the compensated end of the move before it
    (micrometres off the programmed point) and shifts every later move by that: refused, naming the G0 that
    makes the two the same (the test above writes it)."""
    text = "G21 G90 G55\nG0 X10 Y10 Z-20\nG1 X7 Y3 Z-30 F100\nG10 L20 P1 Z2\nG54\nG0 X0 Y0 Z0\nG1 X1\nM2\n"
    with pytest.raises(InputError, match=r"line 4, column 1: 'G10 L20 P1' takes its offset from the current position, "
                                         r"the end of the compensated move of line 3 .*--rapids keep"):
        _frames(tmp_path, ax, text, "linuxcnc")


def test_l20_p0_is_the_active_system_on_linuxcnc(tmp_path, ax):
    _, _, off, _ = _frames(tmp_path, ax, "G55\nG0 X1 Y2 Z3\nG10 L20 P0 X0 Y0 Z0\nG1 X1 F9\nM2\n", "linuxcnc")
    assert np.abs(off[-1] - [201, 102, -147]).max() < TOL_MM


def test_fanuc_l20_sets_the_extended_system_and_haas_the_g154_one(tmp_path, ax):
    """Fanuc: G10 L20 Pn sets G54.1 Pn (the additional work coordinate systems); Haas: G154 Pn."""
    fanuc = "G90 G10 L20 P5 X11 Y22 Z-33\nG54.1 P5\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n"
    _, _, off, _ = _frames(tmp_path, ax, fanuc, "fanuc")
    assert np.abs(off[-1] - [11, 22, -33]).max() < TOL_MM
    haas = "G90 G10 L20 P12 X11 Y22 Z-33\nG154 P12\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n"
    _, _, off, _ = _frames(tmp_path, ax, haas, "haas")
    assert np.abs(off[-1] - [11, 22, -33]).max() < TOL_MM


@pytest.mark.parametrize("text, dialect, where, why", [
    ("G0 X0 Y0 Z0\nG10 L20 P1 X0\n", None, "line 2, column 1", "dialect-dependent"),
    ("G0 X0 Y0 Z0\nG10 L20 P1 X0\n", "mach3", "line 2, column 1", "name the controller with --dialect"),
    ("G91\nG10 L2 P1 X1 Y1 Z1\n", "fanuc", "line 2, column 1", "under G91: Fanuc adds"),
    ("G55\nG0 X1 Y1\nG10 L20 P1 Z0\n", "linuxcnc", "line 3, column 12", "which is not known here"),
    ("G10 L20 P100 X0 Y0 Z0\n", "haas", "line 1, column 9", "expected P1..P99"),
    ("G10 L2 P2 X5\nG55\n", None, "line 2, column 1", "its Y Z are the controller's"),
    ("G10 L20 P2 X0 Y0 Z0 R30\n", "linuxcnc", "line 1, column 21", "rotated work system"),
])
def test_l20_and_l2_refusals(tmp_path, ax, text, dialect, where, why):
    err = _refused(tmp_path, ax, text + "G0 X0 Y0 Z0\nG1 X1 F9\nM2\n", dialect, offsets=None)
    assert f"p.nc: {where}: " in err and why in err, err


# ---------------------------------------------------------------------------- G10 L10 / L11 / L12 / L13
def test_linuxcnc_l10_and_l11_set_the_length_that_makes_the_current_z_read_the_value(tmp_path, ax):
    """LinuxCNC: G10 L10 sets tool P so that, with the offset reloaded, the current Z reads the value (in the
    active system); L11 the same in G59.3. At G55 (Z -150) with tool 1 (150 mm) at program Z -20: machine
    Z = -20 - 150 + 150 = -20; L10 Z5 -> length -20 - (-150) - 5 = 125; L11 Z5 with G59.3 Z -80 (program's
    own L2) -> -20 - (-80) - 5 = 55."""
    text = ("G10 L2 P9 X0 Y0 Z-80\nG55 G43 H1\nG0 X1 Y1 Z-20\nG10 L10 P2 Z5\nG10 L11 P3 Z5\nG43 H2\nG0 Z5\n"
            "G1 X2 F9\nG43 H3\nG0 Z0\nG1 X3\nM2\n")
    _, _, _, tool = _frames(tmp_path, ax, text, "linuxcnc")
    assert abs(tool[0] - 125.0) < TOL_MM and abs(tool[1] - 55.0) < TOL_MM


def test_fanuc_l10_l11_are_geometry_and_wear_both_needed(tmp_path, ax):
    """Fanuc tool offset memory C (and Haas): L10 the H geometry, L11 the H wear; the length is their sum.
    One of them alone leaves the other in the controller's table: refused at the G43 that uses it."""
    text = "G90 G10 L10 P4 R140.\nG10 L11 P4 R-0.02\nG55 G43 H4\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n"
    _, _, _, tool = _frames(tmp_path, ax, text, "fanuc")
    assert abs(tool[0] - 139.98) < TOL_MM
    err = _refused(tmp_path, ax, "G90 G10 L10 P1 R140.\nG55 G43 H1\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n", "fanuc")
    assert "line 2, column 5: 'G43 H1': tool length offset H1: tool 1 is not known" in err
    assert "sets its length geometry only" in err and "set the wear in the program too" in err


def test_haas_l12_l13_are_the_diameter(tmp_path, ax):
    text = ("G90 G10 L12 P1 R10.\nG10 L13 P1 R-0.04\nG55\nG0 X0 Y0 Z0\nG1 G41 D1 X10 F9\nG40 X0\nM30\n")
    p = tmp_path / "p.nc"
    p.write_text(text)
    prog = parse_program(p, axis_words=ax, dialect="haas")
    fr = program_frames(prog, read_work_offsets(OFFSETS), None)
    assert abs(fr.radius([4])[0] - 4.98) < TOL_MM  # (10 - 0.04) / 2


@pytest.mark.parametrize("text, dialect, where, why", [
    ("G10 L10 P1 R140\n", None, "line 1, column 5", "not defined on rs274"),
    ("G10 L12 P1 R10\n", "fanuc", "line 1, column 5", "not defined on fanuc"),
    ("G10 L10 P1 Z5 R1\n", "fanuc", "line 1, column 12", "(the value is R)"),
    ("G10 L10 P1 X1 Z5\n", "linuxcnc", "line 1, column 12", "a tool offset along X"),
])
def test_l10_to_l13_refusals(tmp_path, ax, text, dialect, where, why):
    err = _refused(tmp_path, ax, "G0 X0 Y0 Z0\n" + text + "G1 X1 F9\nM2\n", dialect)
    assert f"p.nc: {where.replace('line 1', 'line 2')}: " in err and why in err, err


# ---------------------------------------------------------------------------- G154
def test_haas_g154_and_g110_select_the_additional_offsets_from_a_file(tmp_path, ax):
    csv_ = read_work_offsets(DATA / "offsets_haas.csv")
    assert csv_.systems["G154P7"] == {"X": 150.0, "Y": 60.0, "Z": -180.0}
    text = "G154 P7\nG0 X0 Y0 Z0\nG1 X1 F9\nG116\nG1 X2\nM30\n"  # G116 = G154 P7
    _, _, off, _ = _frames(tmp_path, ax, text, "haas", offsets=DATA / "offsets_haas.csv")
    assert np.abs(off - [150, 60, -180]).max() < TOL_MM
    err = _refused(tmp_path, ax, "G154 P8\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n", "haas", offsets=DATA / "offsets_haas.csv")
    assert "line 1, column 1: 'G154 P8': the work offset G154P8 is not in" in err
    assert "column 1: 'G154 P100' needs P1..P99" not in err
    err = _refused(tmp_path, ax, "G154 P100\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n", "haas")
    assert "line 1, column 1: 'G154' needs P1..P99" in err
    err = _refused(tmp_path, ax, "G154 P7\nG0 X0 Y0 Z0\nG1 X1 F9\nM30\n", "fanuc")
    assert "line 1, column 1: 'G154': unknown G code" in err


# ---------------------------------------------------------------------------- M62..M68, Siemens native
def test_linuxcnc_outputs_pass_through_and_their_words_are_checked(tmp_path, ax):
    io = ["M62 P0", "M63 P0", "M64 P3", "M65 P3", "M66 P1 L3 Q5", "M66 E0 L0", "M67 E0 Q2.5", "N7 M68 E1 Q0"]
    text = "G55\nG0 X0 Y0 Z0\n" + "\n".join(io) + "\nG1 X1 F9\nM2\n"
    prog, moves, _, _ = _frames(tmp_path, ax, text, "linuxcnc")
    assert prog.classes[2:2 + len(io)] == ["pass"] * len(io) and len(moves) == 1


@pytest.mark.parametrize("line, col, why", [
    ("M62", 1, "'M62' without P"),
    ("M67 E0", 1, "'M67' without Q"),
    ("M66 P1 E2", 1, "P (a digital input) or E (an analog input), one of them"),
    ("M66 P1 L2", 1, "timeout Q > 0"),
    ("M66 P1 L5 Q1", 8, "expected L0..L4"),
    ("M64 P1.5", 5, "expected a channel number"),
    ("M62 P1 G1 X3", 8, "on an M62 line"),
    ("M64 P1 Q2", 8, "it takes P"),
])
def test_output_word_refusals(tmp_path, ax, line, col, why):
    err = _refused(tmp_path, ax, "G55\nG0 X0 Y0 Z0\n" + line + "\nG1 X1 F9\nM2\n", "linuxcnc")
    assert f"p.nc: line 3, column {col}: " in err and why in err, err


@pytest.mark.parametrize("line, dialect, col, word", [
    ('CALL "POCKET1"', "siemens-iso", 1, "'CALL'"),
    ("N20 L100 P2", "siemens-iso", 5, "'L100'"),
    ("G290", None, 1, "'G290'"),
])
def test_siemens_native_calls_are_refused_naming_the_mode(tmp_path, ax, line, dialect, col, word):
    err = _refused(tmp_path, ax, "G55\nG0 X0 Y0 Z0\n" + line + "\nG1 X1 F9\nM30\n", dialect)
    assert f"p.nc: line 3, column {col}: {word}: Siemens native mode" in err and "M98 P" in err, err


# ---------------------------------------------------------------------------- G76 / G87 / G88
def test_fine_back_and_manual_boring_are_kept_by_dialect():
    """Fanuc: G76 fine boring and G88 (manual retract) drill down from R to Z; G87 back boring goes to R below
    the part and feeds up to Z, returning to the initial level."""
    text = ("G0 X0 Y0 Z10\nG98 G76 X5 Y6 Z-20 R2 Q0.5 P100 F50\nG80\nG87 X7 Y8 Z-5 R-30 Q0.5 F50\nG80\n"
            "G88 X9 Y1 Z-12 R1 P500 F50\nG80\n")
    exp = expand_cycles(text, "p", "keep", dialect="fanuc")
    assert [(h.code, h.xyz, h.r) for h in exp.holes] == [
        ("G76", (5.0, 6.0, -20.0), 2.0), ("G87", (7.0, 8.0, -5.0), -30.0), ("G88", (9.0, 1.0, -12.0), 1.0)]
    assert exp.text.splitlines()[slice(*exp.spans[3])] == [  # G87: R below, up to Z, back to the initial level
        "G90 G1 X7.000000 Y8.000000 Z-30.000000 F50", "G1 Z-5.000000", "G0 Z10.000000"]


@pytest.mark.parametrize("text, mode, dialect, why", [
    ("G76 X1 Y1 Z-5 R1 Q1\n", "keep", "linuxcnc", "multi-pass lathe threading"),
    ("G76 X1 Y1 Z-5 R1 Q1\n", "keep", None, "G76 on rs274: dialect-dependent"),
    ("G76 X1 Y1 Z-5 R1 Q1\n", "expand", "fanuc", "has no form in plain moves"),
    ("G87 X1 Y1 Z-5 R-9 Q1\n", "keep", "haas", "read as back boring"),
    ("G99 G87 X1 Y1 Z-5 R-9 Q1\n", "keep", "fanuc", "returns to the initial level only"),
    ("G87 X1 Y1 Z-5 R-2 Q1\n", "keep", "fanuc", "below R"),
])
def test_boring_cycle_refusals(text, mode, dialect, why):
    with pytest.raises(InputError) as exc:
        expand_cycles("G0 X0 Y0 Z10\n" + text, "p.nc", mode, dialect=dialect)
    assert "p.nc: line 2, column " in str(exc.value) and why in str(exc.value), str(exc.value)


# ---------------------------------------------------------------------------- end to end, checked by the truth
@pytest.fixture()
def truth_file(tmp_path):
    mill = load_machine("mill-xyz")
    return ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")


WRONG_MIN_UM = 2.0
"""The same written program judged with the frame a reader that skipped the new words would have used (the G55
of the file instead of L20's, the file's tool instead of L10's/L11's): more than this (observed 4.8-17 μm): the
check has teeth."""


@pytest.mark.parametrize("name, dialect, offsets_file, offsets, tools, wrong", [
    # hand-worked: G154 P12 by L20 = (250, 80, -120); G116 = G154 P7 (the file); tool 1 = 140 - 0.02 mm
    ("haas_g154_g10.nc", "haas", DATA / "offsets_haas.csv",
     {"G154P12": (250, 80, -120), "G116": (150, 60, -180)}, {1: 139.98},
     ({"G154P12": (250, 80, -120), "G116": (150, 60, -180)}, {1: 150.0})),
    # hand-worked: G55 after L20 at (10, 10) = (210, 110, -150); tool 2 by L10 Z5 at Z-20 with tool 1 = 125 mm
    ("linuxcnc_l20_io.ngc", "linuxcnc", OFFSETS, {"G55": (210, 110, -150)}, {1: 150.0, 2: 125.0},
     ({"G55": (200, 100, -150)}, {1: 150.0, 2: 125.0})),
    # bare G43 after T2 M6 / T1 M6: tools 2 (100 mm) and 1 (150 mm); full circles
    ("linuxcnc_bare_g43_circle.ngc", "linuxcnc", OFFSETS, {"G55": (200, 100, -150)}, {1: 150.0, 2: 100.0},
     ({"G55": (200, 100, -150)}, {1: 100.0, 2: 150.0})),
])
def test_programs_with_the_new_words_are_compensated_where_the_part_is_cut(tmp_path, truth_file, name, dialect,
                                                                          offsets_file, offsets, tools, wrong):
    mill = load_machine("mill-xyz")
    out = tmp_path / "o"
    assert main(["compensate", str(DATA / name), "--machine", "mill-xyz", "--model", str(truth_file), "--method",
                 "exact", "--out", str(out), "--truth", str(truth_file), "--dialect", dialect, "--work-offsets",
                 str(offsets_file), "--tool-table", str(TOOLS)]) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["true"]["max_um"] < TOL_POINT_UM
    errs = true_point_errors_um(DATA / name, out / name, mill, ChainElementSet.load(truth_file, mill), offsets,
                                tools, dialect=dialect)
    assert len(errs) >= 5 and errs.max() < TOL_POINT_UM
    errs_wrong = true_point_errors_um(DATA / name, out / name, mill, ChainElementSet.load(truth_file, mill), *wrong,
                                      dialect=dialect)
    assert errs_wrong.max() > WRONG_MIN_UM


# ---------------------------------------------------------------------------- bare G43 / G41, full circles
def test_linuxcnc_bare_g43_and_g41_use_the_tool_loaded_by_m6(tmp_path, ax):
    """LinuxCNC: 'G43' without H and 'G41' without D use the tool in the spindle, the one the last 'Tn M6'
    loaded (tools.csv: tool 2 100 mm r3, tool 1 150 mm r5)."""
    text = "G55\nT2 M6\nG43\nG0 X0 Y0 Z0\nG1 X1 F9\nT1\nM6\nG43\nG41\nG1 X5 Z0\nM2\n"
    p = tmp_path / "p.nc"
    p.write_text(text)
    prog = parse_program(p, axis_words=ax, dialect="linuxcnc")
    fr = program_frames(prog, read_work_offsets(OFFSETS), read_tool_table(TOOLS))
    _, tool = fr.at([4, 9])
    assert list(tool) == [100.0, 150.0] and fr.radius([9])[0] == 5.0
    err = _refused(tmp_path, ax, "G55\nG43\nG0 X0 Y0 Z0\nG1 X1 F9\nM2\n", "linuxcnc")
    assert "line 2, column 1: 'G43' without H uses the tool in the spindle, which the program has not loaded" in err
    err = _refused(tmp_path, ax, "G55\nT2 M6\nG43\nG0 X0 Y0 Z0\nG1 X1 F9\nM2\n", "fanuc")
    assert "line 3, column 1: 'G43' without H (the current tool's length)" in err


def test_a_centre_format_arc_without_axis_words_is_a_full_circle(tmp_path, ax):
    """RS274NGC / LinuxCNC / Fanuc: G2/G3 with I J and no axis words ends where it starts: a full circle."""
    prog, moves, _, _ = _frames(tmp_path, ax, "G55\nG0 X50 Y50 Z0\nG3 I-20 F9\nG2 I10\nI10\nM2\n", "linuxcnc")
    arcs = [m for m in moves if m.kind == "arc"]
    assert len(arcs) == 3 and all(np.array_equal(m.start, m.end) for m in arcs)
    assert (arcs[0].arc["uc"], arcs[0].arc["vc"], arcs[0].arc["sweep"]) == (30.0, 50.0, 2 * np.pi)
    assert arcs[1].arc["sweep"] == -2 * np.pi and arcs[2].arc["uc"] == 60.0
    err = _refused(tmp_path, ax, "G55\nG0 X50 Y50 Z0\nG3 R20 F9\nM2\n")
    assert "line 3, column 4: 'R20' without axis words (only a centre-format G2/G3 full circle" in err


def test_g80_with_a_motion_code_names_the_dialects_that_run_it(tmp_path, ax):
    err = _refused(tmp_path, ax, "G55\nG0 G80 G90 X0 Y0 Z0\nG1 X1 F9\nM30\n")
    assert "line 2, column 4: 'G80' and 'G0' on one line (same modal group); Fanuc, Haas" in err
    assert "name the controller with --dialect" in err
    _frames(tmp_path, ax, "G55\nG0 G80 G90 X0 Y0 Z0\nG1 X1 F9\nM30\n", "fanuc")  # read on Fanuc


def test_an_incremental_move_after_a_kept_cycle_needs_an_absolute_z_first():
    """After a kept G99 hole the controller is at the written (compensated) R, a few μm from the programmed R
    the reader continues from: an incremental move would carry that difference silently. Refused until an
    absolute Z; expanded cycles (whose retract is written as programmed) are not affected."""
    text = "G0 X0 Y0 Z10\nG99 G81 X5 Y5 Z-5 R2 F100\nG80\nG91 G1 X5\nG90 G1 Z5\nG91 G1 X5\n"
    with pytest.raises(InputError) as exc:
        expand_cycles(text, "p.nc", "keep")
    assert "p.nc: line 4, column 8: an incremental move after the kept canned cycle of line 2" in str(exc.value)
    expand_cycles(text, "p.nc", "expand")
    expand_cycles(text.replace("G91 G1 X5\nG90 G1 Z5\n", "G90 G1 Z5\n"), "p.nc", "keep")  # absolute Z first: read


@pytest.mark.parametrize("line, dialect", [("G10 L1 P1 Z120", None), ("G10 L10 P1 Z5", "linuxcnc"),
                                           ("G10 L11 P1 R0.01", "haas")])
def test_a_g10_changing_the_active_tool_length_is_refused(tmp_path, ax, line, dialect):
    """When a controller applies a changed length of the active tool (at once, or at the next G43) is
    controller-dependent: refused; set the tool before selecting it, or cancel it (G49) first."""
    err = _refused(tmp_path, ax, f"G55 G43 H1\nG0 X0 Y0 Z0\n{line}\nG1 X1 F9\nM2\n", dialect)
    assert "p.nc: line 3, column 1: " in err and "changes tool 1, whose length offset is active (G43 H1)" in err, err
    _frames(tmp_path, ax, f"G55 G49\nG0 X0 Y0 Z0\n{line}\nG1 X1 F9\nM2\n" if dialect != "haas" else
            f"G55 G49\nG0 X0 Y0 Z0\n{line}\nG10 L10 P1 R100\nG43 H1\nG1 X1 Z0 F9\nM2\n", dialect)


@pytest.mark.parametrize("arc, dialect, refused", [
    ("G2 X20 Y0 I10.004 J0", "linuxcnc", (-0.008, 10.004)),  # 8 μm on r 10 mm: within 28.3 μm (LinuxCNC runs it)
    ("G2 X20 Y0 I10.004 J0", None, "more than 2 μm"),  # the reader's own 2 μm without the controller
    # 60 μm (0.6 %): above 28.3 μm and 0.1 % both
    ("G2 X20 Y0 I10.03 J0", "linuxcnc", "more than 2.828 mm, or both 28.28 μm and 0.10% of the radius"),
    ("G2 X2 Y0 I1.004 J0", "linuxcnc", (-0.008, 1.004)),  # 8 μm on r 1 mm (0.8 %): within 28.3 μm, so it runs
    ("G2 X6000 Y0 I3000.05 J0", "linuxcnc", (-0.1, 3000.05)),  # 100 μm on r 3 m (0.0033 %): within 0.1 %, runs
    ("G2 X20000 Y0 I10001.5 J0", "linuxcnc", "more than 2.828 mm"),  # 3 mm on r 10 m (0.03 %): above 100 · 28.3 μm
    # Fanuc: its tolerance is a machine parameter (3410), not in the program: the reader's 2 μm, the rule named
    ("G2 X20 Y0 I10.004 J0", "fanuc", "(more than 2 μm; Fanuc: parameter 3410 sets the tolerance"),
])
def test_linuxcnc_reads_centre_arcs_with_its_own_radius_tolerance(tmp_path, ax, arc, dialect, refused):
    """LinuxCNC 2.9 (interp_arc.cc arc_data_ijk; G-code reference, "Center Format Arcs", "It is an error if"): an
    error when the radii differ by d > 100 · 2·0.01·√2 mm, or by d > 2·0.01·√2 mm (G21) *and* more than 0.1 %
    of the radius; otherwise run as a spiral (radius linear in the angle), as read here. ``refused``: the refusal's
    words, or (r1 − r0 mm, the centre's X mm) of the arc read."""
    text = f"G21 G55\nG0 X0 Y0 Z0\nG1 X0 F9\n{arc}\nM2\n"
    if isinstance(refused, tuple):
        _, moves, _, _ = _frames(tmp_path, ax, text, dialect)
        a = moves[-1].arc
        assert abs((a["r1"] - a["r0"]) - refused[0]) < TOL_MM * 1e3 and np.isclose(a["uc"], refused[1])
    else:
        assert f"p.nc: line 4, column 4: 'X" in (err := _refused(tmp_path, ax, text, dialect)) and refused in err, err


@pytest.mark.parametrize("arc, refused", [
    ("G3 X1.6875 I0.0688 J0", None),  # centre 1.61875 written to 0.0001 in: the radii differ by 0.0001 in (2.54 μm)
    ("G3 X1.6875 I0.0691 J0", "differ by 17.780 μm (more than 7.184 μm; Fanuc: parameter 3410"),  # 0.0007 in: more than rounding
])
def test_inch_arcs_rounded_to_four_decimals_are_read(tmp_path, ax, arc, refused):
    """A 4-decimal inch program (as CAM posts write G20 output; Fanuc manual, "Circular interpolation"): a
    centre rounded to 0.0001 inch makes the radii differ by up to that much; under G20 the reader accepts
    2·0.0001·√2 inch (7.18 μm) and reads the arc as the spiral the controller runs; more is refused."""
    text = f"G20 G55\nG0 X1.55 Y0 Z0\nG1 X1.55 F9.\n{arc}\nM30\n"
    if refused is None:
        _, moves, _, _ = _frames(tmp_path, ax, text, "fanuc")
        a = moves[-1].arc
        assert abs((a["r1"] - a["r0"]) - (-0.0001 * 25.4)) < TOL_MM * 1e3 and np.isclose(a["uc"], 1.6188 * 25.4)
    else:
        assert "p.nc: line 4, column 4: 'X1.6875'" in (err := _refused(tmp_path, ax, text, "fanuc")) and refused in err, err


def test_fanuc_h_word_alone_changes_the_length_offset_and_h0_is_zero(tmp_path, ax):
    """Fanuc 0i manual, tool length compensation: in G43 mode a new H number replaces the offset (not added);
    H00's offset is always 0; in G49 mode an H word is only held; a changed offset needs Z written again. Tools 1 (150 mm) and 2 (100 mm) of the table.
    Without a dialect an H outside G43 stays refused."""
    text = ("G21 G55\nG53 G0 Z0 H0\nG0 X0 Y0 Z0\nG1 X1. F100.\nG43 H1 Z10.\nG1 X10.\nH2\nG1 X20. Z10.\n"
            "G53 G0 Z0 H0\nG1 Z50.\nM30\n")
    _, moves, _, tool = _frames(tmp_path, ax, text, "fanuc")  # the feed moves (rapids are kept as written)
    assert [tuple(m.end) for m in moves] == [(1, 0, 0), (1, 0, 10), (10, 0, 10), (20, 0, 10), (20, 0, 50)]
    assert np.allclose(tool, [np.nan, 150.0, 150.0, 100.0, np.nan], atol=TOL_MM, equal_nan=True)  # NaN: no offset
    assert "p.nc: line 2, column 11: 'H0' outside G43" in (err := _refused(tmp_path, ax, text)) and "--dialect" in err, err
