"""Programs as CAM posts write them (benchmarks/nc_styles/p*: Fusion 360 Haas and Fanuc, Mastercam, SOLIDWORKS CAM,
NX, FeatureCAM, Makino, Siemens ISO, Mach3, grbl, a Haas shop program), each written for this project from its
post's or controller's manual wording: read with --dialect auto and the shop's tables (nc_styles/tables),
compensated, and judged independently of the reader (benchmarks/suite/gcode_checks.py ``independent_check``:
non-motion lines byte-identical, every programmed point and every hole bottom reached by the TRUE machine within
1 μm). The words they need, one test each from the manual's wording; what stays ambiguous refused by line,
column and word with the option that reads it."""
import csv
import re
import json
from pathlib import Path

import pytest

from benchmarks.suite.gcode_checks import independent_check
from benchmarks.suite.gcode_corpus import FAMILIES, STYLE_TABLES, STYLES, style_tables
from compensation.app.cli import main
from compensation.dialects import detect_dialect
from compensation.gcode import AxisWords, parse_program
from compensation.nc_cycles import expand_cycles
from errormap.chain_elements import ChainElementSet
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM

POSTS = [r for r in csv.DictReader(FAMILIES.open(encoding="utf-8")) if r["file"].startswith("p")]
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), as the corpus count."""


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture(scope="module")
def truth_file(tmp_path_factory, mill):
    return ChainElementSet.random(mill, 101, ELEMENT_SCALE_UM, 11).save(tmp_path_factory.mktemp("t") / "truth.json")


@pytest.mark.parametrize("row", POSTS, ids=[r["file"] for r in POSTS])
def test_cam_post_program_is_compensated_where_the_part_is_cut(tmp_path, truth_file, capsys, row):
    prog = STYLES / row["file"]
    out = tmp_path / "o"
    assert main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(truth_file), "--truth",
                 str(truth_file), "--method", "exact", "--out", str(out), "--dialect", "auto", "--work-offsets",
                 str(STYLE_TABLES / "offsets.csv"), "--tool-table", str(STYLE_TABLES / "tools.csv")]) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    verdict = independent_check(prog, out / row["file"], "auto", truth_file, *style_tables())
    assert verdict.startswith("ok: "), verdict


def test_the_check_sees_an_uncompensated_or_shifted_hole(tmp_path, truth_file):
    """The program itself as its 'compensated' output, and a written hole moved by 10 μm: both WRONG."""
    prog = STYLES / "p03_mastercam_fanuc.nc"
    same = tmp_path / "same" / prog.name  # the check writes beside the written program: a copy, in tmp_path
    same.parent.mkdir()
    same.write_bytes(prog.read_bytes())
    assert independent_check(prog, same, "auto", truth_file, *style_tables()).startswith("WRONG")
    out = tmp_path / "o"
    assert main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(truth_file), "--method", "exact",
                 "--out", str(out), "--work-offsets", str(STYLE_TABLES / "offsets.csv"), "--tool-table",
                 str(STYLE_TABLES / "tools.csv")]) == 0
    text = (out / prog.name).read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("N154 X"))
    x = float(line.split()[1][1:])
    bad = tmp_path / prog.name
    bad.write_text(text.replace(line, line.replace(f"X{x:.6f}", f"X{x + 0.010:.6f}")))
    assert "WRONG: hole of line 36" in independent_check(prog, bad, "auto", truth_file, *style_tables())


def _hole_lines(text, dialect=None):
    return expand_cycles(text, "p.nc", "expand", dialect=dialect).text.splitlines()


def test_tool_length_offset_before_a_cycle_keeps_x_y():
    """Mastercam: 'G0 G90 G54 X15. Y15.', 'G43 H4 Z50.', then 'G98 G81 Z-3. R2.' with no X Y: the tool length is
    along Z (G17), so the hole is at the X Y of before; Z is known again from the G43 line's absolute Z."""
    lines = _hole_lines("G0 G90 G54 X15. Y15.\nG43 H4 Z50.\nG98 G81 Z-3. R2. F120.\nG80\n", "fanuc")
    assert lines[2:6] == ["G90 G0 X15.000000 Y15.000000", "G0 Z2.000000", "G1 Z-3.000000 F120.", "G0 Z50.000000"]


def test_g28_moves_only_the_axes_it_names():
    """'G91 G28 Z0.' returns Z to the reference (Z unknown after), X and Y stay where they were."""
    lines = _hole_lines("G0 X5 Y6 Z10\nG91 G28 Z0\nG90 G0 Z20\nG81 Z-3 R1 F9\nG80\n", "fanuc")
    assert lines[3:7] == ["G90 G0 X5.000000 Y6.000000", "G0 Z1.000000", "G1 Z-3.000000 F9", "G0 Z20.000000"]
    with pytest.raises(InputError, match=r"line 3, column 5: G81: the Z before the cycle .* not known after G28"):
        _hole_lines("G0 X5 Y6 Z10\nG91 G28 Z0\nG90 G81 Z-3 R1 F9\n", "fanuc")


def test_g98_after_g99_returns_to_the_initial_level_on_fanuc():
    """Fanuc 0i, Haas: G98 returns to the initial level (the Z when the cycle mode began: 10), also after G99
    holes of the series (which return to R: 1); refused where the controller is not named (older LinuxCNC returns
    to the Z at the line's start)."""
    text = "G0 X0 Y0 Z10\nG99 G81 X1 Z-3 R1 F9\nG98 X2\nG80\n"
    for dialect in ("fanuc", "haas", "siemens-iso"):
        lines = _hole_lines(text, dialect)
        assert lines[1:5] == ["G90 G0 X1.000000 Y0.000000", "G0 Z1.000000", "G1 Z-3.000000 F9", "G0 Z1.000000"]
        assert lines[5:9] == ["G90 G0 X2.000000 Y0.000000", "G0 Z1.000000", "G1 Z-3.000000 F9", "G0 Z10.000000"]
    with pytest.raises(InputError, match=r"line 3, column 1: G81 G98 after a G99 hole .* --dialect fanuc"):
        _hole_lines(text, "linuxcnc")


def _read(tmp_path, text, dialect):
    p = tmp_path / "p.nc"
    p.write_text("G21 G90 G17\nG0 X10 Y10 Z-20\n" + text + "G1 X30 F100\nM30\n", encoding="latin-1")
    return parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect)


def test_g80_with_g0_in_the_safe_start_line_under_auto(tmp_path):
    """'G0 G17 G40 G49 G80 G90' (Mastercam, FeatureCAM, Mach3 posts): Fanuc, Haas, Siemens ISO and Mach3 take the
    G0, LinuxCNC refuses the line; under --dialect auto with no dialect word it is read as G0, the line named."""
    prog = _read(tmp_path, "G0 G17 G40 G49 G80 G90 X20 Y20\n", "auto")
    assert prog.dialect == "rs274" and prog.g80_line == 3
    assert "G80, G28 or G30 with a G0-G3 on one line" in prog.dialect_evidence
    moved = [m for m in prog.moves if m.index == 2]
    assert moved and moved[0].kind == "rapid" and list(moved[0].end[:2]) == [20.0, 20.0]
    for dialect in ("linuxcnc", None):
        with pytest.raises(InputError, match=r"line 3, column \d+: 'G80' and 'G0' on one line"):
            _read(tmp_path, "G0 G17 G40 G49 G80 G90 X20 Y20\n", dialect)


def test_haas_g187_with_e_and_bare_g103_are_modes(tmp_path):
    """Haas mill manual: 'G187 Pn Ennn' (P1-P3 smoothness, E the corner rounding: a tolerance, not a path),
    'G187' alone (back to Settings 191/85), 'G103' alone (= P0). The moves are the programmed ones."""
    prog = _read(tmp_path, "G187 P3 E0.01\nG103 P1\nM130 (tool1.png)\nG1 X20 F500\nG103\nG187\n", "haas")
    assert [m.end[0] for m in prog.moves if m.compensate] == [20.0, 30.0]  # the G0 kept (--rapids keep)
    assert [ev[3] for ev in prog.events if ev[2] == "mode"] == ["G187", "G103", "G103", "G187"]


@pytest.mark.parametrize("text, dialect, col, what", [
    ("G187 P3 E0\n", "haas", 9, "'E0' with G187: it takes P1 (rough), P2 (medium) or P3 (finish)"),
    ("G187 P4 E0.01\n", "haas", 6, "'P4' with G187"),
    ("G1 X20 E0.01\n", "haas", 8, "'E0.01': extruder / unknown axis"),
    ("G187 P3 E0.01\n", "fanuc", 1, "'G187': unknown G code"),
])
def test_g187_words_out_of_place_are_refused(tmp_path, text, dialect, col, what):
    with pytest.raises(InputError) as err:
        _read(tmp_path, text, dialect)
    assert f"line 3, column {col}: " in str(err.value) and what in str(err.value), str(err.value)


@pytest.mark.parametrize("text, evidence", [
    ("N10 G08 P1\nG0 X0\n", "G08 P1 preview control"),
    ("G05 P10000 (HPCC)\nG0 X0\n", "G05 P10000 high-precision contour control"),
    ("N40 M29 S500\nG84 X1 Y1 Z-5 R2 F500\n", "M29 S rigid tapping"),
])
def test_fanuc_look_ahead_lines_name_the_dialect(text, evidence):
    assert detect_dialect(text) == ("fanuc", evidence)
    assert detect_dialect("G5 X1 Y2 I0 J1 P1 Q0\n")[0] == "rs274"  # a LinuxCNC spline is no marker


def test_fanuc_dwell_by_x_and_aicc_level_move_nothing(tmp_path):
    """Fanuc 0i-MF 'G04 X_' is a dwell of X seconds (Siemens ISO mode as Fanuc); Fanuc 30i 'G05.1 Q1 Rn' (R1-R10, the
    machining quality level: a tolerance). Neither moves: the moves are the programmed ones."""
    for dialect in ("fanuc", "siemens-iso"):
        prog = _read(tmp_path, "G05.1 Q1 R5\nG04 X1.5\nG1 X20 F500\nG05.1 Q0\n", dialect)
        assert [list(m.end) for m in prog.moves if m.compensate] == [[20.0, 10.0, -20.0], [30.0, 10.0, -20.0]]


@pytest.mark.parametrize("text, dialect, col, what", [
    ("G04 X1.5\n", "haas", 5, "axis word 'X1.5' with G4 (a dwell time on some controls"),  # Haas: G04 P only
    ("G04 X1.5\n", "linuxcnc", None, None),  # LinuxCNC: the X is a move after the dwell (read, not refused)
    ("G04 X1.5 Y2.\n", "fanuc", 5, "axis word 'X1.5' with G4"),
    ("G05.1 Q1 R11\n", "fanuc", 10, "only 'G05.1 Q1 R1'-'R10'"),
    ("G05.1 Q0 R5\n", "fanuc", 10, "only 'G05.1 Q1 R1'-'R10'"),
])
def test_dwell_and_aicc_words_out_of_place(tmp_path, text, dialect, col, what):
    if what is None:
        prog = _read(tmp_path, text, dialect)
        assert [m.end[0] for m in prog.moves if m.index == 2] == [1.5]
        return
    with pytest.raises(InputError) as err:
        _read(tmp_path, text, dialect)
    assert f"line 3, column {col}: " in str(err.value) and what in str(err.value), str(err.value)


def _tools(prog):
    return [ev[3] for ev in prog.events if ev[2] == "tool"]


def test_bare_g43_takes_the_modal_h_where_the_readings_agree(tmp_path):
    """Fanuc, Haas, Siemens ISO: the H number is modal, so 'G43 Z5.' while 'G43 H1' is in force is H1 again (after
    G49 it is not read); LinuxCNC and Mach3 take the tool M6 loaded. With no dialect word a bare G43 is read where both give one tool;
    where they differ, or no H was given (Fanuc's H00), it is refused naming the word."""
    assert _tools(_read(tmp_path, "T1 M6\nG43 Z100. H1\nG43 Z5.\n", "auto")) == [1, 1]
    assert _tools(_read(tmp_path, "T2 M6\nG43 Z100. H1\nG43 Z5.\n", "fanuc")) == [1, 1]
    assert _tools(_read(tmp_path, "T2 M6\nG43 Z100. H1\nG49\nG43 Z5.\n", "linuxcnc")) == [1, None, 2]
    for text, dialect in (("T2 M6\nG43 Z100. H1\nG43 Z5.\n", "auto"), ("T1 M6\nG43 Z5.\n", "fanuc"),
                          ("T1 M6\nG43 Z100. H1\nG49\nG43 Z5.\n", "fanuc")):  # after G49: not read
        with pytest.raises(InputError, match=r"line \d+, column 1: 'G43' without H"):
            _read(tmp_path, text, dialect)


def test_grbl_system_commands(tmp_path):
    """grbl v1.1 '$' commands: views and $X pass, $H (homing) leaves the position unknown until an absolute word;
    a '$' line names the dialect; a jog or a setting is refused by line and column."""
    prog = _read(tmp_path, "$X\n$G\n$H\nG0 X5 Y5 Z-10\n", "auto")
    assert prog.dialect == "grbl" and [list(m.end) for m in prog.moves if m.compensate] == [[30.0, 5.0, -10.0]]
    with pytest.raises(InputError, match=r"line 4, column 8: incremental 'X1' before X is known"):
        _read(tmp_path, "$H\nG91 G1 X1\nG90\n", "grbl")
    for text, what in (("$J=G91 X10 F100\n", "'$J=G91 X10 F100'"), ("$100=250\n", "'$100=250'")):
        with pytest.raises(InputError, match=rf"line 3, column 1: grbl system command {re.escape(what)}"):
            _read(tmp_path, text, "grbl")


def test_m97_is_a_call_on_haas_only_and_grbl_has_no_calls(tmp_path):
    """Haas mill manual: 'M97 P2000' runs the local subprogram at block N2000 (it names Haas under --dialect auto);
    Fanuc and Mach3 have no M97 call, grbl no subprogram calls at all: refused naming the word and the option."""
    sub = "M97 P2000\nM30\nN2000 G1 X3.\nM99\n"
    assert _read(tmp_path, sub, "auto").dialect == "haas"
    for dialect, what in (("fanuc", "M97: M97 is Haas's local subprogram call, not a call on fanuc (name --dialect "
                                    "haas)"), ("grbl", "M97: grbl has no subprogram calls")):
        with pytest.raises(InputError, match=rf"line 3, column 1: {re.escape(what)}"):
            _read(tmp_path, sub, dialect)
    with pytest.raises(InputError, match=r"line 3, column 1: M98: grbl has no subprogram calls"):
        _read(tmp_path, "M98 P1001\nM30\nO1001\nG1 X2.\nM99\n", "grbl")


def test_bare_g70_g71_on_a_mill_are_units_under_auto(tmp_path):
    """NX's generic posts write 'G40 G17 G90 G70' (inch) / 'G71' (mm): on a machine with X and Y, with no dialect word,
    a G70/G71 with no other word is inch/mm wherever it runs (a lathe cycle needs its P Q / U W words); the line is
    named. A named dialect, or any other word on the line, keeps it refused."""
    prog = _read(tmp_path, "G40 G17 G90 G70\nG1 X1. Y1.\nG71\n", "auto")
    assert prog.g80_line == 3 and "a bare G70/G71 is inch/mm; first at line 3" in prog.dialect_evidence
    ends = [list(m.end) for m in prog.moves if m.compensate]
    assert ends == [pytest.approx([25.4, 25.4, -20.0]), pytest.approx([30.0, 25.4, -20.0])]  # inch, then mm again
    for text, dialect, col in (("G71\n", "fanuc", 1), ("G71 P10 Q20 U0.5 W0.1\n", "auto", 1)):
        with pytest.raises(InputError, match=rf"line 3, column {col}: 'G71' \(lathe cycle"):
            _read(tmp_path, text, dialect)


def _cutters(prog):
    return [ev[3] for ev in prog.events if ev[2] == "cutter"]


def test_a_d_word_alone_sets_the_cutter_offset_number_on_fanuc(tmp_path):
    """Fanuc, Haas, Siemens ISO: 'G43 Z15. H1 D1' sets D1 (modal) and moves nothing more; a later 'G41' without D uses
    it. With no dialect word only they run such a line (LinuxCNC refuses a D without G41/G42), so it is read so there,
    and a bare G41 where that D is also the tool M6 loaded; refused where the readings differ."""
    text = "T2 M6\nG43 Z15. H1 D1\nG41 X5. Y1.\nG1 X20.\nD2\nG1 X25.\nG40 X27.\n"
    assert _cutters(_read(tmp_path, text, "fanuc")) == [1, 2, None]
    with pytest.raises(InputError, match=r"line 5, column 1: 'G41' without D"):
        _read(tmp_path, text, "auto")  # M6 loaded tool 2, D1 given: LinuxCNC-like and Fanuc readings differ
    assert _cutters(_read(tmp_path, text.replace("T2 M6", "T1 M6"), "auto")) == [1, 2, None]
    with pytest.raises(InputError, match=r"line 4, column 13: 'D1' outside G41/G42"):
        _read(tmp_path, text, "linuxcnc")


def test_g86_without_p_is_kept_on_fanuc_and_haas():
    """Fanuc 0i-MF / Haas 'G86 X Y Z R F' has no dwell (LinuxCNC's G86 needs P): kept, its hole at the bottom."""
    text = "G0 X0 Y0 Z15.\nG98 G86 X10. Y10. Z-10. R5. F50.\nG80\n"
    for dialect in ("fanuc", "haas"):
        exp = expand_cycles(text, "p.nc", "keep", dialect=dialect)
        assert [h.xyz for h in exp.holes] == [(10.0, 10.0, -10.0)] and exp.holes[0].r == 5.0
    with pytest.raises(InputError, match=r"line 2, column 5: G86 without P"):
        expand_cycles(text, "p.nc", "keep", dialect="linuxcnc")


def test_g0_with_g28_on_one_line(tmp_path):
    """'G0 G28 G91 Z0.' / 'G91 G00 G28 Z0.' (Fanuc, Haas, Siemens ISO: G28 takes the axis words, the G0 stays the
    motion mode): read there and, named in the summary, with no dialect word; LinuxCNC refuses two axis-word codes."""
    text = "G0 G28 G91 Z0.\nG90\nG0 Z5.\nG1 X20. F100\n"
    for dialect in ("fanuc", "haas", "auto"):
        prog = _read(tmp_path, text, dialect)
        assert [list(m.end) for m in prog.moves if m.compensate][:1] == [[20.0, 10.0, 5.0]]
    assert _read(tmp_path, text, "auto").g80_line == 3
    with pytest.raises(InputError, match=r"line 3, column 4: 'G28' with a motion code on the same line; Fanuc"):
        _read(tmp_path, text, "linuxcnc")
