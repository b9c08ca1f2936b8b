"""Fanuc/Haas lathe grooving / peck cycles G74 / G75 (compensation/nc_groove.py). Programs written here from the
manuals' formats (Fanuc 0i-TF two-block ``G75 R(e)`` / ``G75 X Z P(Δi) Q(Δk) F``, ``G74 R(e)`` / ``G74 Z Q(Δk) F``;
Haas one-block ``G75 X I F``), not copied.

Checked independently of the expander: the moves each cycle makes are rebuilt here from the manual's rule
(:func:`hand_moves`: pecks of Δk each returned by e, to the bottom, back to the start's level, across by Δi, …, back
to the start point), not from the expander's output; the lines that are not the cycle are the source's byte for
byte; every rebuilt point is reached, in order, by a written move whose TRUE tool tip (averaged over one turn) lies
within :data:`TOL_POINT_UM` of it; no C word is written while turning."""
import json
import re
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.suite.gcode_checks import lathe_points_reached
from compensation.app.cli import main
from compensation.nc_groove import ACROSS_UM
from compensation.turning import parse_lathe_program
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.machine import load_machine

LATHE = "lathe-xzc"
SEED = 101
"""The truth: ``ChainElementSet.random(lathe, SEED, SCALE_UM, N_STATIONS)`` (as the lathe benchmark's), also the
model (``--method exact``): what is left is the solver's residual (~1e-4 um) and what the cycle cannot follow."""
SCALE_UM = 10.0
N_STATIONS = 11
TOL_POINT_UM = 1.0
"""A programmed point is reached when the true tip is this close (the issue's bound, the corpus check's)."""
PART_Z_MM = 200.0
"""The work offset's Z (the part's face 200 mm along the bed, inside Z's stroke)."""

HEAD = "G21 G18 G40 G99\nT0101\nG96 S120 M03\n"
TAIL = "G00 X100. Z50.\nM05\nM30\n"
G75_SERIES = HEAD + "G00 X62. Z-20.\nG75 R0.5\nG75 X40. Z-30. P2000 Q2500 F0.08\n" + TAIL
"""A 10 mm wide groove from Z-20 to Z-30 down to X40 (diameter) with a narrower tool: pecks of 2 mm (radius) returned
0.5 mm, columns 2.5 mm apart (5 columns)."""
G74_DRILL = HEAD.replace("G96 S120", "G97 S800") + "G00 X0. Z3.\nG74 R1.\nG74 Z-25. Q5000 F0.1\n" + TAIL
"""A face peck drill on the spindle's axis: pecks of 5 mm returned 1 mm, to Z-25 (one column: no X, no P)."""
G74_FACE = HEAD + "G00 X30. Z2.\nG74 R0.3\nG74 X40. Z-4. P1500 Q2000 F0.05\n" + TAIL
"""A face groove from X30 to X40 (diameters), 4 mm deep from Z2: pecks of 2 mm returned 0.3, columns 1.5 mm apart."""
G75_KEPT = HEAD + "G00 X70. Z-20.\nG01 X62. F0.2\nG75 X61. P300 F0.08\nG00 X100. Z50.\nM05\nM30\n"
"""One plunge (no Z, no Q) of 0.5 mm (radius) from a compensated approach: kept, its X compensated at the bottom."""
HAAS_KEPT = ("G20 G18 G40 G99\nT0101\nG97 S600 M03\nG00 X2.8 Z-0.8\nG01 X2.45 F0.01\nG75 X2.41 I0.01 F0.002\n"
             "G00 X4. Z2.\nM05\nM30\n")
"""Haas one-block G75 in inch: one plunge of 0.02 in (radius) in pecks of I, kept."""


def hand_moves(code, start, end, peck_mm, shift_mm, e_mm):
    """The manual's moves (Fanuc 0i-TF G74/G75), rebuilt here: ``[(G code, X radius mm, Z mm)]`` from the start
    point (X radius, Z) to the return there."""
    pl = 1 if code == "G74" else 0  # the plunge axis' index in (X radius, Z)
    s, t = start[pl], end[pl]
    a0, a1 = start[1 - pl], end[1 - pl]
    sign_p, sign_a = np.sign(t - s), np.sign(a1 - a0)
    across = [a0]
    while abs(a1 - across[-1]) > shift_mm + 1e-9:
        across.append(across[-1] + sign_a * shift_mm)
    if abs(a1 - across[-1]) > 1e-9:
        across.append(a1)
    pt = (lambda a, p: (a, p)) if code == "G74" else (lambda a, p: (p, a))
    out = []
    for i, a in enumerate(across):
        if i:
            out.append(("G0",) + pt(a, s))
        depth = peck_mm
        while depth < abs(t - s) - 1e-9:
            out += [("G1",) + pt(a, s + sign_p * depth), ("G0",) + pt(a, s + sign_p * (depth - e_mm))]
            depth += peck_mm
        out += [("G1",) + pt(a, t), ("G0",) + pt(a, s)]
    return out + [("G0",) + pt(a0, s)]


def _setup(tmp_path):
    truth = tmp_path / "truth.json"
    ChainElementSet.random(load_machine(LATHE), SEED, SCALE_UM, N_STATIONS).save(truth)
    (tmp_path / "off.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{PART_Z_MM}\n")
    (tmp_path / "tools.csv").write_text("tool,length_mm,radius_mm\n1,0,0.8\n")
    return truth


def _compensate(tmp_path, text, dialect="fanuc", extra=()):
    truth = _setup(tmp_path)
    src = tmp_path / "p.nc"
    src.write_text(text)
    out = tmp_path / "out"
    rc = main(["compensate", str(src), "--machine", LATHE, "--model", str(truth), "--truth", str(truth),
               "--method", "exact", "--dialect", dialect, "--lathe-x", "diameter", "--out", str(out),
               "--work-offsets", str(tmp_path / "off.csv"), "--tool-table", str(tmp_path / "tools.csv"), *extra])
    written = out / "p.nc"
    lines = [ln for ln in written.read_text().splitlines() if not ln.startswith("(volcomp:")] if rc == 0 else []
    return rc, lines, truth


def _reached(truth, expected, moves):
    """``(max error um, points)``: each expected point (X radius, Z) reached, in order, by a written move (TRUE tip,
    mean over one turn, within TOL_POINT_UM of it)."""
    lathe = load_machine(LATHE)
    field = ChainField(lathe, ChainElementSet.load(truth, lathe))
    src = [SimpleNamespace(end=np.array([x, z, 0.0]), index=i) for i, (_, x, z) in enumerate(expected)]
    errs, missed = lathe_points_reached(field, lathe, src, moves, (0.0, PART_Z_MM), TOL_POINT_UM)
    assert missed is None, f"expected point {missed} reached by no written move"
    return max(errs), len(errs)


@pytest.mark.parametrize("text", [G75_SERIES, G75_SERIES.replace("T0101\n", "T0101\nG00 C0.\n")],
                         ids=["xz", "c-axis-before"])
def test_g75_series_expanded_reaches_every_point_of_the_manuals_moves(tmp_path, text):
    """With a C-axis move before the spindle starts the program is read with C (kept): the cycle's moves, while
    turning, still get no C word."""
    rc, out, truth = _compensate(tmp_path, text, extra=("--expand-cycles",))
    assert rc == 0
    src = text.splitlines()
    at = src.index("G75 X40. Z-30. P2000 Q2500 F0.08")
    tail = len(src) - at - 1
    assert out[:at] == src[:at] and out[-tail:] == src[at + 1:]  # every other line byte for byte (G75 R0.5 too)
    inserted = out[at:-tail]
    assert not any("C" in ln for ln in inserted)  # turning: C never written
    expected = hand_moves("G75", (31.0, -20.0), (20.0, -30.0), 2.0, 2.5, 0.5)
    assert sum(ln.startswith("G1") for ln in inserted) == sum(c == "G1" for c, _, _ in expected) == 30
    assert inserted[0].endswith(" F0.08") and not any(" F" in ln for ln in inserted[1:])
    (tmp_path / "bare.nc").write_text("\n".join(out) + "\n")
    prog, _ = parse_lathe_program(tmp_path / "bare.nc", load_machine(LATHE), "keep", None, "fanuc", "diameter")
    err, n = _reached(truth, expected, [m for m in prog.moves if at <= m.index < len(out) - tail])
    assert n == len(expected) == 65 and err <= TOL_POINT_UM
    summary = json.loads((tmp_path / "out" / "compensate_summary.json").read_text())["files"][0]
    assert summary["true"]["max_um"] <= TOL_POINT_UM < summary["true_uncompensated"]["max_um"]  # the check has teeth
    assert summary["lathe_cycles"] == [f"line {at + 1} (expanded line {at + 1}): G75 (diameter grooving cycle) "
                                       "expanded: 5 column(s), "
                                       "30 feed(s), written as 65 moves compensated point by point (the rapids too)"]


@pytest.mark.parametrize("text,code,start,end,peck,shift,e", [
    (G74_DRILL, "G74", (0.0, 3.0), (0.0, -25.0), 5.0, None, 1.0),
    (G74_FACE, "G74", (15.0, 2.0), (20.0, -4.0), 2.0, 1.5, 0.3),
    (G75_SERIES, "G75", (31.0, -20.0), (20.0, -30.0), 2.0, 2.5, 0.5)])
def test_expanded_text_is_the_manuals_moves(tmp_path, text, code, start, end, peck, shift, e):
    """The written expansion (before compensation) is exactly the rebuilt moves, in absolute X (diameter) Z."""
    p = tmp_path / "p.nc"
    p.write_text(text)
    prog, _ = parse_lathe_program(p, load_machine(LATHE), "keep", None, "fanuc", "diameter", cycles="expand")
    src = text.splitlines()
    at = next(i for i, ln in enumerate(src) if ln.startswith(code) and "Q" in ln)
    lines = [ln.rstrip("\n") for ln in prog.lines]
    new = lines[at:len(lines) - (len(src) - at - 1)]
    got = [(m.group(1), float(m.group(2)) / 2.0, float(m.group(3)))
           for m in (re.match(r"(G[01]) X(-?[\d.]+) Z(-?[\d.]+)", ln) for ln in new)]
    want = hand_moves(code, start, end, peck, shift or np.inf, e)
    assert [g[0] for g in got] == [w[0] for w in want]
    assert np.allclose([g[1:] for g in got], [w[1:] for w in want], rtol=0, atol=1e-9)


def test_g74_drill_on_the_axis_is_written_at_the_closest_approach(tmp_path, capsys):
    """On the spindle's axis (X0) the tip's offset across (the tool's centre height) is what X and Z cannot correct:
    every point of the drill is written where the tip passes nearest the axis (compensation.turning), reported as
    such, not as failures; each peck's Z reached, its radius within TOL_POINT_UM of the least any X reaches (the corpus
    check's search, not the compensator's)."""
    rc, out, truth = _compensate(tmp_path, G74_DRILL, extra=("--expand-cycles",))
    assert rc == 0
    assert "15 point(s) on the spindle axis (line(s) 6), not failures" in capsys.readouterr().out
    src = G74_DRILL.splitlines()
    at = src.index("G74 Z-25. Q5000 F0.1")
    tail = len(src) - at - 1
    assert out[:at] == src[:at] and out[-tail:] == src[at + 1:]  # every other line byte for byte
    entry = json.loads((tmp_path / "out" / "compensate_summary.json").read_text())["files"][0]
    axis = entry["spindle_axis_points"]
    assert entry["failures"] == 0 and axis["count"] == entry["points"] == 15
    assert {str(line).split()[0] for line in axis["lines"]} == {str(at + 1)} and axis["model_max_here"]
    header = [ln for ln in (tmp_path / "out" / "p.nc").read_text().splitlines() if "on the spindle axis" in ln]
    assert len(header) == 1 and header[0].startswith("(volcomp: 15 point[s] on the spindle axis [line[s] 6]")
    lathe = load_machine(LATHE)
    field = ChainField(lathe, ChainElementSet.load(truth, lathe))
    expected = hand_moves("G74", (0.0, 3.0), (0.0, -25.0), 5.0, np.inf, 1.0)  # one column: no shift
    (tmp_path / "bare.nc").write_text("\n".join(out) + "\n")
    prog, _ = parse_lathe_program(tmp_path / "bare.nc", lathe, "keep", None, "fanuc", "diameter")
    src_pts = [SimpleNamespace(end=np.array([x, z, 0.0]), index=i) for i, (_, x, z) in enumerate(expected)]
    on_axis = []
    written = [m for m in prog.moves if at <= m.index < len(out) - tail]
    errs, missed = lathe_points_reached(field, lathe, src_pts, written, (0.0, PART_Z_MM), TOL_POINT_UM, on_axis)
    assert missed is None and len(errs) == len(expected) and max(errs) <= TOL_POINT_UM
    floors = np.array([f for _, f in on_axis])
    assert len(on_axis) == len(expected) and floors.min() > 1.0  # every point: its centre height, not reachable
    assert abs(floors.max() - axis["residual_max_um"]) <= TOL_POINT_UM  # the summary's residual is that floor


def _kept_check(tmp_path, text, dialect, cycle, approach, start, bottom, unit):
    rc, out, truth = _compensate(tmp_path, text, dialect)
    assert rc == 0
    src = text.splitlines()
    i, j = src.index(cycle), src.index(approach)
    assert [ln for k, ln in enumerate(out) if k not in (i, j)] == [ln for k, ln in enumerate(src) if k not in (i, j)]
    x_w = re.search(r"X(-?[\d.]+)", out[i]).group(1)
    assert out[i] == re.sub(r"X-?[\d.]+", "X" + x_w, cycle)  # only the plunge word's number changed
    z_ctrl = float(re.search(r"Z(-?[\d.]+)", out[j]).group(1))  # where the control stands across: the approach's Z
    run = [SimpleNamespace(end=np.array([float(x_w) / 2 * unit, z_ctrl * unit, 0.0]), index=0)]
    err, n = _reached(truth, [("G1", bottom[0], bottom[1])], run)
    summary = json.loads((tmp_path / "out" / "compensate_summary.json").read_text())["files"][0]
    across = summary["lathe_grooves"][0]["across_um"]
    assert n == 1 and err <= TOL_POINT_UM and across <= ACROSS_UM
    assert summary["lathe_grooves"][0]["line"] == i + 1 and not any("C" in ln for ln in out)
    return err, across


def test_a_one_plunge_g75_is_kept_with_its_bottom_compensated(tmp_path):
    err, across = _kept_check(tmp_path, G75_KEPT, "fanuc", "G75 X61. P300 F0.08", "G01 X62. F0.2", (31.0, -20.0),
                              (30.5, -20.0), 1.0)
    assert err <= across + 1e-3  # what is left: the error across, plus the solver's residual


def test_haas_one_block_g75_kept_in_inch(tmp_path):
    _kept_check(tmp_path, HAAS_KEPT, "haas", "G75 X2.41 I0.01 F0.002", "G01 X2.45 F0.01", (1.225 * 25.4, -0.8 * 25.4),
                (1.205 * 25.4, -0.8 * 25.4), 25.4)


REFUSED = [  # program, dialect, extra options, (line, column), words of the reason
    (G75_SERIES, "fanuc", (), "line 6, column 1: 'G75' (diameter grooving cycle) of several columns",
     "use --expand-cycles"),
    (G75_KEPT.replace("X61. P300", "X40. P2000"), "fanuc", (), "line 6, column 1: 'G75' kept: the control plunges at "
     "the Z it stands at", "use --expand-cycles"),
    (G75_SERIES.replace("G75 R0.5\n", ""), "fanuc", ("--expand-cycles",), "line 5, column 1: 'G75': the return after "
     "each peck e is the control's parameter 5139", "write the first block 'G75 R(e)'"),
    (HAAS_KEPT, "haas", ("--expand-cycles",), "line 6, column 1: 'G75' on Haas: the return after each peck is a "
     "control setting", "leave --expand-cycles out"),
    (G75_SERIES.replace("P2000", "P2."), "fanuc", (), "line 6, column 16: 'P2.' on a G75 line: Fanuc reads P and Q "
     "in the least input increment without a decimal point", "write it so"),
    (G75_SERIES.replace("X40. Z-30.", "U-22. Z-30."), "fanuc", (), "line 6, column 5: 'U-22.' on a G75 line: "
     "incremental U is not read", "write the end point as absolute X and Z"),
    (G75_SERIES.replace("F0.08", "F0.08 R0.3"), "fanuc", ("--expand-cycles",), "line 6, column 1: 'R0.3' (the "
     "relief at the bottom) on the G75 line", "leave --expand-cycles out"),
    (G75_SERIES.replace("F0.08", "F0.08 M08"), "fanuc", (), "line 6, column 34: 'M08' on a fanuc G75 line: only",
     "write other words on a line of their own"),
    (G75_SERIES.replace("G75 R0.5", "G75 R3."), "fanuc", ("--expand-cycles",), "line 6, column 1: 'G75': the return "
     "e (3 mm) is more than the peck P (2 mm)", "the control alarms"),
    (G75_SERIES.replace("G75 X40. Z-30.", "G75 Z-30."), "fanuc", (), "line 6, column 1: 'G75' without X", "end point"),
    (G75_SERIES.replace("G00 X62.", "G00 G42 X62."), "fanuc", (), "line 6, column 1: 'G75' with tool nose radius "
     "compensation (G42) in force", "cancel it (G40) before"),
]


@pytest.mark.parametrize("text,dialect,extra,where,how", REFUSED, ids=[r[3].split(": ", 1)[1][:40] for r in REFUSED])
def test_refusals_name_line_column_word_and_the_option(tmp_path, capsys, text, dialect, extra, where, how):
    rc, _, _ = _compensate(tmp_path, text, dialect, extra)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc != 0 and where in err and how in err and "Traceback" not in err
