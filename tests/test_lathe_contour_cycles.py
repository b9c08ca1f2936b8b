"""Fanuc/Haas lathe contour cycles (compensation/nc_contour.py): G71/G72/G73 roughing and G70 finishing whose
contour blocks N(ns)..N(nf) are written in the program. Programs written here from the manuals' formats (Fanuc
0i-TF two-block ``G71 U R`` / ``G71 P Q U W F``; Haas one-block ``G71 P Q U W D F``), not copied.

Checked independently of the reader's frames: the lines that are not compensated moves are the source's byte for
byte; every programmed contour point is reached, in order, by a written move whose TRUE tool tip (averaged over one
turn) lies within :data:`TOL_POINT_UM` of the programmed surface of revolution; no C word is written while turning."""
import json

import numpy as np
import pytest

from benchmarks.suite.gcode_checks import lathe_points_reached
from benchmarks.suite.lathe import G70_LINE, STEPS  # the stepped shaft the lathe benchmark counts
from compensation.app.cli import main
from compensation.nc_contour import HOLD_UM
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine

LATHE = "lathe-xzc"
SEED = 101
N_STATIONS = 11
SCALE_UM = 10.0
"""The truth: a seeded element set (errormap.chain_elements.ChainElementSet.random), σ 10 um / urad at 11 stations."""
TOL_POINT_UM = 1.0
"""A programmed point is reached when the true tip is this close (the corpus check's tolerance; the model is the
truth here, so what is left is the solver's residual, ~1e-4 um)."""
PART_Z_MM = 200.0
"""The work offset's Z (the part's face 200 mm along the bed, inside Z's stroke)."""

FANUC = """%
O0002
G21 G18 G40 G99
T0101
G50 S2000
G96 S180 M03
G00 X62. Z3.
G71 U1. R0.5
G71 P100 Q200 U0.4 W0.1 F0.25
N100 G00 X18.
G01 X22. Z-2. F0.12
X34. Z-20.
X46. Z-32.
N200 X60. Z-44.
G70 P100 Q200
G01 Z-50. F0.2
G00 X100. Z50.
M05
M30
%
"""
"""Two-block G71 (type I: N100 gives X only), a monotonic taper contour, G70 on it, then a feed along Z whose X is
the cycle's start point's (X62.), not the contour's end (X60.)."""

HAAS = """%
O0003
G20 G18 G40 G99
T0101
G50 S2500
G97 S1000 M03
G00 X2.5 Z0.1
G96 S900
G72 P10 Q20 U0.01 W0.005 D0.02 F0.01
N10 G00 Z-1.2
G01 X2.2 Z-1. F0.006
X1.6 Z-0.6
X0.8 Z-0.2
N20 X0.2 Z0.
G70 P10 Q20
G00 X3. Z1.
M05
M30
%
"""
"""Haas one-block G72 (facing, type I: N10 gives Z only), inch, contour monotonic in both axes."""


def _setup(tmp_path, tools="tool,length_mm,radius_mm\n1,0,0.8\n"):
    truth = tmp_path / "truth.json"
    ChainElementSet.random(load_machine(LATHE), SEED, SCALE_UM, N_STATIONS).save(truth)
    (tmp_path / "off.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{PART_Z_MM}\n")
    (tmp_path / "tools.csv").write_text(tools)
    return truth


def _compensate(tmp_path, text, dialect, name="p.nc", extra=(), **tools):
    truth = _setup(tmp_path, **tools)
    src = tmp_path / name
    src.write_text(text)
    out = tmp_path / "out"
    rc = main(["compensate", str(src), "--machine", LATHE, "--model", str(truth), "--truth", str(truth),
               "--method", "exact", "--dialect", dialect, "--lathe-x", "diameter", "--out", str(out),
               "--work-offsets", str(tmp_path / "off.csv"), "--tool-table", str(tmp_path / "tools.csv"), *extra])
    return rc, src, out / name, truth


def _check(src, written, dialect, truth):
    """Independent check (module docstring): ``(max error um, points, lines kept)``."""
    lathe = load_machine(LATHE)
    bare = written.with_suffix(".bare")
    bare.write_text("".join(ln for ln in written.read_text().splitlines(True) if not ln.startswith("(volcomp:")))
    (p_src, _), (p_out, _) = (parse_lathe_program(f, lathe, "keep", None, dialect, "diameter") for f in (src, bare))
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    keep_src = [ln for i, ln in enumerate(p_src.lines) if i not in {m.index for m in m_src}]
    keep_out = [ln for i, ln in enumerate(p_out.lines) if i not in {m.index for m in m_out}]
    assert keep_src == keep_out  # cycle lines and every other line byte-identical
    assert not any("C" in ln.split("(")[0].upper() for ln in p_out.lines if ln not in p_src.lines)
    return _reached(m_src, m_out, truth) + (len(keep_src),)


def _reached(m_src, m_out, truth):
    """``(max error um, points)``: each programmed point of ``m_src`` reached, in order, by a move of ``m_out``
    whose TRUE tip (averaged over one turn) is within TOL_POINT_UM of it (the corpus count's lathe check)."""
    lathe = load_machine(LATHE)
    errs, missed = lathe_points_reached(ChainField(lathe, ChainElementSet.load(truth, lathe)), lathe, m_src, m_out,
                                        (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None, f"line {missed} reached by no written move"
    return max(errs), len(errs)


@pytest.mark.parametrize("text,dialect,codes", [(FANUC, "fanuc", ("G71", "G70")), (HAAS, "haas", ("G72", "G70"))])
def test_contour_points_compensated_cycle_lines_kept(tmp_path, text, dialect, codes):
    rc, src, written, truth = _compensate(tmp_path, text, dialect)
    assert rc == 0
    err, n, _ = _check(src, written, dialect, truth)
    assert err <= TOL_POINT_UM and n >= 4  # the feeds (N(ns) is a G0, kept)
    out = written.read_text()
    for line in text.splitlines():
        if line.split(" ")[0] in codes or line.startswith(("G71", "G72", "G70")):
            assert line in out.splitlines()  # the cycle lines as written
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    cycles = summary["lathe_cycles"]
    assert [c.split(": ")[1].split(" ")[0] for c in cycles] == list(codes)
    assert "computed by the controller from the compensated contour" in cycles[0]
    assert "exactly the compensated contour" in cycles[1]
    assert summary["true"]["max_um"] < summary["true_uncompensated"]["max_um"]


def test_the_last_contour_block_keeps_its_number_on_its_end(tmp_path):
    rc, src, written, _ = _compensate(tmp_path, FANUC, "fanuc")
    assert rc == 0
    out = written.read_text().splitlines()
    n200 = [i for i, ln in enumerate(out) if ln.startswith("N200")]
    g70 = out.index("G70 P100 Q200")
    assert len(n200) == 1 and out[n200[0] + 1] == "G70 P100 Q200" and g70 == n200[0] + 1


def test_after_the_cycle_the_tool_is_at_its_start_point(tmp_path):
    """The feed after G70 (``G01 Z-50.``) starts from the cycle's start point: its X is X62. (radius 31), not
    the contour's last X60."""
    lathe = load_machine(LATHE)
    p = tmp_path / "p.nc"
    p.write_text(FANUC)
    prog, _ = parse_lathe_program(p, lathe, "keep", None, "fanuc", "diameter")
    after = [m for m in prog.moves if m.index == FANUC.splitlines().index("G01 Z-50. F0.2")][0]
    assert after.start[0] == pytest.approx(31.0) and after.end[0] == pytest.approx(31.0)


def _refusal(tmp_path, text, capsys):
    rc, *_ = _compensate(tmp_path, text, "fanuc")
    assert rc != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "Traceback" not in err and len(err) < 300 + len(str(tmp_path))
    return err


@pytest.mark.parametrize("old,new,where", [
    ("G71 P100 Q200 U0.4 W0.1 F0.25\nN100", "G71 P100 Q200 U0.4 W0.1 F0.25\nG00 X70.\nN100",
     "line 10, column 1: the G71 on line 9 names its contour's first block N100"),
    ("G01 X22. Z-2. F0.12", "G01 X22. Z-2. F0.12 M08", "line 11, column 21: 'M08' in the contour blocks"),
    ("X34. Z-20.", "X34. Z-20. T0202", "line 12, column 12: 'T0202' in the contour blocks"),
    ("G70 P100 Q200", "G70 P300 Q200", "line 15, column 5: 'G70 P300 Q200': no G71/G72/G73 before it"),
    ("N200 X60. Z-44.", "N201 X60. Z-44.", "line 15, column 1: 'G70' inside the contour blocks N100-N200"),
    ("N200 X60. Z-44.\nG70", "N201 X60. Z-44.\nM30\n%\n(", "line 15, column 1: 'M30' in the contour blocks N100-N200 of the G71 on line 9"),
    ("G71 P100 Q200 U0.4 W0.1 F0.25", "G71 P100 Q200 U0.4 W0.1 F0.25 M08", "line 9, column 31: 'M08' on a G71"),
])
def test_refusals_name_line_column_word_and_the_rule(tmp_path, capsys, old, new, where):
    err = _refusal(tmp_path, FANUC.replace(old, new), capsys)
    assert where in err


MONO = FANUC.replace("N100 G00 X18.\nG01 X22. Z-2. F0.12\nX34. Z-20.\nX46. Z-32.\nN200 X60. Z-44.",
                    "N100 G00 X20.\nG01 Z-15. F0.15\nX30. Z-25.\nZ-40.\nG02 X40. Z-45. R5.\nN200 G01 X52.")
"""A contour with axis-parallel blocks (``Z-40.``, ``N200 G01 X52.``): a step the program gives along one axis only
may come out of compensation with a small step back along the other."""


def test_a_small_back_step_is_held_and_the_points_still_reached(tmp_path):
    """With this seed's truth the compensated Z of ``N200 G01 X52.`` (line 15) goes back 0.21 um against the
    contour's Z direction: it is held at the previous point's Z (HOLD_UM), listed, and the point still checks."""
    rc, src, written, truth = _compensate(tmp_path, MONO, "fanuc")
    assert rc == 0
    entry = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    assert [h.split(":")[0] for h in entry["lathe_contour_held"]] == ["line 15"]
    assert "Z held at the previous point's" in entry["lathe_contour_held"][0]
    err, _, _ = _check(src, written, "fanuc", truth)
    assert err <= HOLD_UM + 1e-3  # the held point's error, at most the hold (plus the solver's residual)


def test_compensation_that_breaks_a_monotonic_contour_is_refused(tmp_path, capsys):
    """A 60 mm Z-only block then an X-only last block: with this seed's truth the compensated Z of ``N200 X40.``
    (line 9) goes back ~4 um against the contour's Z direction, more than HOLD_UM: the controller would alarm on
    that contour, so the program is refused naming the line and the axis."""
    text = ("G21 G18 G40 G99\nT0101\nG96 S180 M03\nG00 X110. Z3.\nG71 U1. R0.5\nG71 P100 Q200 U0.4 W0.1 F0.25\n"
            "N100 G00 X20.\nG01 Z-60. F0.15\nN200 X40.\nG70 P100 Q200\nG00 X150. Z50.\nM05\nM30\n")
    err = _refusal(tmp_path, text, capsys)
    assert "line 9: compensation moves Z back by" in err and "G71 contour of line 6" in err and "use --expand-cycles" in err


def test_the_contour_end_past_the_file_is_refused(tmp_path, capsys):
    err = _refusal(tmp_path, FANUC.split("N200")[0] + "N201 X60. Z-44.\n", capsys)
    assert "line 9, column 1: 'G71 P100 Q200': the contour's blocks N100-N200 do not follow it" in err


def test_g73_has_no_monotonic_rule_and_the_first_block_is_kept(tmp_path):
    text = MONO.replace("G71 U1. R0.5", "G73 U2. W1. R3").replace("G71 P100", "G73 P100")
    rc, src, written, truth = _compensate(tmp_path, text, "fanuc")
    assert rc == 0
    assert "G73 U2. W1. R3" in written.read_text().splitlines()
    err, _, _ = _check(src, written, "fanuc", truth)
    assert err <= TOL_POINT_UM


@pytest.mark.parametrize("dialect,hint", [("fanuc", "in Fanuc G-code system C"), ("haas", None)])
def test_a_cycle_without_p_q_is_refused_naming_the_word(tmp_path, capsys, dialect, hint):
    text = FANUC.replace("G71 P100 Q200 U0.4 W0.1 F0.25", "G71")
    rc, *_ = _compensate(tmp_path, text, dialect)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and f"line 9, column 1: 'G71' on a {dialect} lathe: a contour cycle needs P(ns) and Q(nf)" in err
    assert (hint in err) if hint else ("system C" not in err)


@pytest.mark.parametrize("line,code,why", [("G92 X29.2 Z-20. F1.5", "G92", "kept as a cycle"),
                                           ("G76 P021060 Q100 R0.05", "G76", "its passes")])
def test_threading_cycles_are_refused_saying_why(tmp_path, capsys, line, code, why):
    """On a Fanuc lathe G92 is the thread cutting cycle (not a coordinate offset): kept, it is refused naming
    --expand-cycles; G76 is refused (tests/test_lathe_threading.py checks G32 and the expanded G92)."""
    text = FANUC.replace("G70 P100 Q200\n", f"G70 P100 Q200\nG00 X30. Z5.\n{line}\n")
    err = _refusal(tmp_path, text, capsys)
    assert f"line 17, column 1: '{code}'" in err and why in err


def test_after_a_cycle_the_next_move_names_its_motion_code(tmp_path, capsys):
    """Which G0-G3 the control keeps after a contour cycle the manuals leave open: a move with axis words alone
    right after G70 is refused naming the word, not read with the contour's last G code."""
    err = _refusal(tmp_path, FANUC.replace("G01 Z-50. F0.2", "Z-50. F0.2"), capsys)
    assert "line 16, column 1: axis word 'Z-50.' but no motion mode" in err


def _contour_event(kind, code="G71"):
    return [(4, 1, "lathe-contour", (2, 5, 1, kind), code)]


@pytest.mark.parametrize("kind,axis,back_um,outcome", [
    ("type I", 0, 0.3, "held"), ("type I", 0, 2.0, "refused"), ("type I", 1, 2.0, "refused"),
    ("type II", 0, 2.0, "kept"), ("type II", 1, 2.0, "refused"), ("type II", 1, 0.3, "held")])
def test_which_axes_a_contour_keeps_monotonic(kind, axis, back_um, outcome):
    """G71 type I: X and Z monotonic; type II: Z only (X may have pockets). A contour of 4 points (lines 2-5) rising
    in X and falling in Z as programmed; the compensated third point steps back by ``back_um`` on ``axis``."""
    from compensation.nc_contour import hold_back_steps
    from errormap.io import InputError
    axes_d = np.array([[10.0, 0.0, 0.0], [12.0, -5.0, 0.0], [14.0, -10.0, 0.0], [16.0, -15.0, 0.0]])
    axes = axes_d.copy()
    axes[2, axis] = axes[1, axis] - (1 if axis == 0 else -1) * back_um * 1e-3  # against the contour's direction
    if outcome == "refused":
        with pytest.raises(InputError, match=f"line 4: compensation moves {'XZ'[axis]} back by"):
            hold_back_steps("p.nc", _contour_event(kind), [2, 3, 4, 5], axes_d, axes, 0, 1)
        return
    out, rows, held = hold_back_steps("p.nc", _contour_event(kind), [2, 3, 4, 5], axes_d, axes, 0, 1)
    if outcome == "held":
        assert rows.tolist() == [2] and out[2, axis] == axes[1, axis] and held[0].startswith("line 4: ")
    else:
        assert rows.size == 0 and np.array_equal(out, axes)


@pytest.mark.parametrize("length2,refused", [(5.0, True), (0.0, False)])
def test_g70_with_another_tools_offsets_is_refused(tmp_path, capsys, length2, refused):
    """The contour is compensated at the roughing tool's offsets; a G70 run by a tool with other offsets would cut
    the other tool's points: refused naming the line; with the same offsets it is read."""
    text = FANUC.replace("G70 P100 Q200\nG01 Z-50. F0.2\n", "T0202\nG70 P100 Q200\n")  # T: the position unknown
    _setup(tmp_path)
    (tmp_path / "tools.csv").write_text(f"tool,length_mm,radius_mm\n1,0,0.8\n2,{length2},0.4\n")
    src = tmp_path / "p.nc"
    src.write_text(text)
    rc = main(["compensate", str(src), "--machine", LATHE, "--model", str(tmp_path / "truth.json"), "--method",
               "exact", "--dialect", "fanuc", "--lathe-x", "diameter", "--out", str(tmp_path / "out"),
               "--work-offsets", str(tmp_path / "off.csv"), "--tool-table", str(tmp_path / "tools.csv")])
    err = capsys.readouterr().err
    assert (rc != 0) == refused
    assert ("line 16, column 1: 'G70': its tool's offsets (X, Z) [0.0, 5.0] mm differ" in err) == refused


@pytest.mark.parametrize("dialect,r1,kind", [("fanuc", "", "type II"), ("haas", "", "type I"),
                                             ("haas", " R1", "type II")])
def test_type_ii_by_the_first_block_and_on_haas_r1(tmp_path, dialect, r1, kind):
    """N(ns) with X and Z: type II on Fanuc; on Haas only with R1 on the cycle line (else checked as type I)."""
    p = tmp_path / "p.nc"
    p.write_text(FANUC.replace("N100 G00 X18.", "N100 G00 X18. Z3.").replace("W0.1 F0.25", f"W0.1 F0.25{r1}"))
    prog, _ = parse_lathe_program(p, load_machine(LATHE), "keep", None, dialect, "diameter")
    assert [e[3][3] for e in prog.events if e[2] == "lathe-contour"] == [kind]




def test_expand_cycles_writes_g70_as_its_moves_where_in_place_is_refused(tmp_path, capsys):
    """In place, compensation breaks the contour's monotonic Z (refused naming --expand-cycles); with
    --expand-cycles the G71 and its contour are kept as written, G70 becomes the contour's moves compensated point
    by point (each programmed point reached by the TRUE machine within TOL_POINT_UM) and a G0 back to the start."""
    rc, *_ = _compensate(tmp_path, STEPS, "fanuc")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and "compensation moves" in err and "use --expand-cycles" in err
    rc, src, written, truth = _compensate(tmp_path, STEPS, "fanuc", extra=("--expand-cycles",))
    assert rc == 0
    out = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]
    lines = STEPS.splitlines()
    tail = len(lines) - G70_LINE - 1
    assert out[:G70_LINE] == lines[:G70_LINE] and out[-tail:] == lines[G70_LINE + 1:]  # G71, contour: as written
    inserted = out[G70_LINE:-tail]
    assert inserted[-1] == "G00 X110. Z3." and not any("C" in ln or "N" in ln for ln in inserted)
    lathe = load_machine(LATHE)
    p_src, _ = parse_lathe_program(src, lathe, "keep", None, "fanuc", "diameter")
    bare = written.with_suffix(".bare")
    bare.write_text("\n".join(out) + "\n")
    p_out, _ = parse_lathe_program(bare, lathe, "keep", None, "fanuc", "diameter")
    first, last = G70_LINE, len(out) - tail - 1
    contour = [m for m in p_src.moves if m.compensate and 6 <= m.index <= 12]
    finish = [m for m in p_out.moves if first <= m.index <= last]
    err_um, n = _reached(contour, [m for m in finish if m.compensate], truth)
    assert err_um <= TOL_POINT_UM and n == len(contour) == 6
    assert finish[-1].index == last and finish[-1].end[:2] == pytest.approx([55.0, 3.0], abs=1e-9)  # radius, Z
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    # --expand-cycles: the program is written as its flat one, so every note names the source line and the written
    # line (docs/reference/tool-paths.md, "Line numbers in the summary"); G71 and its contour come before the G70
    assert summary["lathe_cycles"][0].startswith("line 6 (expanded line 6): G71 P100 Q200") and "uncompensated" in \
        summary["lathe_cycles"][0] and "roughing accuracy is not the part's" in summary["lathe_cycles"][0]
    assert summary["lathe_cycles"][1].startswith("line 14 (expanded line 14): G70 P100 Q200 expanded: the contour's "
                                                 "blocks (lines 7 (expanded line 7) to 13 (expanded line 13))")
    assert summary["true"]["max_um"] <= TOL_POINT_UM < summary["true_uncompensated"]["max_um"]


@pytest.mark.parametrize("old,new,where", [
    ("G01 Z-30. F0.15", "G01 Z-30.", "line 8: a feed block of the G70 on line 14 before any F of its contour"),
    ("G00 X150. Z50.", "G01 X150. Z50.", "line 15: a feed block after the expanded G70 of line 14 before the "
                                         "program gives F again"),
    ("G70 P100 Q200", "G70 P100 Q200 F0.1", "line 14, column 15: 'F0.1' on a G70 line"),
])
def test_expand_cycles_refuses_a_feed_the_manual_leaves_open(tmp_path, capsys, old, new, where):
    """Fanuc 0i-TF: in G70 the F S T of the contour's blocks are in effect; the F before the contour's first F,
    after the finishing pass, or on the G70 line the manual does not give: refused naming the line and the option."""
    rc, *_ = _compensate(tmp_path, STEPS.replace(old, new), "fanuc", extra=("--expand-cycles",))
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and where in err and "leave --expand-cycles out" in err and "Traceback" not in err


def test_expand_cycles_moves_the_g70_lines_number_to_its_first_move(tmp_path):
    rc, _, written, _ = _compensate(tmp_path, STEPS.replace("G70 P100", "N300 G70 P100"), "fanuc",
                                    extra=("--expand-cycles",))
    out = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]
    assert rc == 0 and out[G70_LINE] == "N300 G00 X20." and sum(ln.startswith("N") for ln in out) == 3


def test_expand_cycles_in_inch_returns_to_the_start_point_in_the_programs_words(tmp_path):
    """Haas one-block G72 in inch, X in diameters: the return is written in the program's own words (X2.5 Z0.1)."""
    rc, src, written, truth = _compensate(tmp_path, HAAS, "haas", extra=("--expand-cycles",))
    out = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]
    g70 = HAAS.splitlines().index("G70 P10 Q20")
    assert rc == 0 and "G70 P10 Q20" not in out and out[:g70] == HAAS.splitlines()[:g70]
    assert out[out.index("G00 X3. Z1.") - 1] == "G00 X2.5 Z0.1"


def test_expand_cycles_with_a_c_axis_section_after_it(tmp_path):
    """The G70's moves shift the lines after it: the spindle's state (turning or C-axis mode) is read on the lines
    written, so the C-axis move after M05 is compensated with its C and the G70's moves, while turning, get no C."""
    text = STEPS.replace("T0101\n", "T0101\nG00 C0.\n").replace("M05\nM30\n", "M05\nT0100\nG00 X150. Z50. C45.\n"
                                                                   "G01 X120. F0.3\nM30\n")
    rc, src, written, truth = _compensate(tmp_path, text, "fanuc", extra=("--expand-cycles",))
    out = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")]
    t = out.index("T0100")
    assert rc == 0 and any(" C" in ln for ln in out[t + 1:])  # C-axis mode: C compensated with X and Z
    assert not any("C" in ln for ln in out[G70_LINE + 1:t])  # the G70's moves, while turning: no C
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    assert summary["true"]["max_um"] <= TOL_POINT_UM


def test_expand_cycles_finishes_with_another_tools_offsets(tmp_path):
    """Written as moves, the G70's contour is compensated at the finishing tool's own offsets (in place it is
    refused: the contour's points are the roughing tool's)."""
    text = STEPS.replace("G70 P100 Q200\n", "T0202\nG00 X110. Z3.\nG70 P100 Q200\n")
    rc, src, written, truth = _compensate(tmp_path, text, "fanuc", extra=("--expand-cycles",),
                                          tools="tool,length_mm,radius_mm\n1,0,0.8\n2,5.0,0.4\n")
    summary = json.loads((written.parent / "compensate_summary.json").read_text())["files"][0]
    assert rc == 0 and summary["true"]["max_um"] <= TOL_POINT_UM < summary["true_uncompensated"]["max_um"]
