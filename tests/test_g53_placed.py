"""Moves in machine coordinates (``G53``) placed in the program's frame, and LinuxCNC's rule on arcs whose radii differ.

``G53 G0 Z..`` (LinuxCNC G-code reference, "G53 Move in Machine Coordinates"; Fanuc, "Machine coordinate system
selection"): the axis goes to that machine position; the program's own position there is the machine value minus
the active work offset, the G92 offset and (on Z) the active tool length. Given the tables, the reader carries it,
so a move after the G53 that leaves Z out (Fusion 360 for Personal Use: "high feed G1 instead of G0" before the
first ``G43``) is compensated as any other; without a work-offset table the G53 position cannot be placed and the
move is refused naming ``--work-offsets``.

Test programs written for this project from the manual wording of each case, not copied files."""
import json

import numpy as np
import pytest

from benchmarks.suite.gcode_checks import independent_check
from compensation.app.cli import main
from compensation.gcode import AxisWords, move_points, parse_program
from compensation.nc_state import read_tool_table, read_work_offsets
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM

TOL_MM = 1e-9
"""Positions are differences of a few numbers of up to 6 digits: exact to round-off."""
ELEMENT_SCALE_UM = 10.0
"""Truth elements of ±10 μm / μrad (1 σ), as the corpus count."""
MAX_CORRECTION_MM = 0.2
"""The truth's corrections stay well under this (errors of tens of μm): a written Z differs from the program's by
the compensation only."""
OFFSETS = {"G54": (200.0, 100.0, -300.0), "G55": (260.0, 150.0, -250.0)}
TOOLS = {1: 100.0, 2: 90.5}

# Fusion 360 for Personal Use, Fanuc-style post: its G53 home (here 5 mm below the Z home, inside the stroke after
# compensation), the "high feed G1 F5000. instead of G0" positioning before G43, a second tool after a G53 with
# G43 H1 still active
FUSION = """%
O1001
(Using high feed G1 F5000. instead of G0.)
N10 G90 G94 G17
N15 G21
N20 G53 G0 Z-5.
N25 T1 M6
N30 S5000 M3
N35 G54
N40 G1 X20. Y10. F5000.
N45 G0 G43 Z15. H1
N50 G1 Z-1. F300.
N55 X40.
N60 G2 X50. Y20. I0. J10.
N65 G1 Y40.
N70 G0 Z15.
N75 G53 G0 Z-5.
N80 T2 M6
N85 S6000 M3
N90 G1 X30. Y30. F5000.
N95 G0 G43 Z10. H2
N100 G1 Z-2. F300.
N105 X35.
N110 G53 G0 Z-5.
N115 M30
%
"""

# LinuxCNC: a G53 under G55, a G92 offset and inch units (G53 numbers are in the active units)
LINUXCNC = """G21 G90 G55
G0 X0 Y0 Z0
G92 Z10
G20 G53 G0 Z-1.
G21 G1 X5 F100
G53 G0 X300 Y150
G1 Z2
M2
"""


@pytest.fixture()
def tables(tmp_path):
    off = tmp_path / "offsets.csv"
    off.write_text("system,x_mm,y_mm,z_mm\n" + "".join(f"{s},{x},{y},{z}\n" for s, (x, y, z) in OFFSETS.items()))
    tls = tmp_path / "tools.csv"
    tls.write_text("tool,length_mm,radius_mm\n" + "".join(f"{n},{v},3\n" for n, v in TOOLS.items()))
    return off, tls


def _read(tmp_path, text, tables, dialect="auto", fast=True):
    p = tmp_path / "p.nc"
    p.write_text(text)
    given = None if tables is None else (read_work_offsets(tables[0]), read_tool_table(tables[1]))
    return parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), dialect=dialect, tables=given,
                         fast=fast)


def _end(prog, line):
    return next(m.end for m in prog.moves if m.index == line - 1)


@pytest.mark.parametrize("fast", [True, False])
def test_the_move_after_a_g53_starts_at_the_machine_position_in_the_program_frame(tmp_path, tables, fast):
    """N20 G53 Z-5 in the power-on G54, no tool length: program Z = -5 - (-300) = 295; N75 with G43 H1 (100 mm):
    -5 + 300 - 100 = 195. The feed moves after them start there (both readers: block-wise and per line)."""
    prog = _read(tmp_path, FUSION, tables, fast=fast)
    first = next(m for m in prog.moves if m.index == 9)  # N40 (line 10)
    assert first.compensate and np.abs(first.end - [20.0, 10.0, 295.0]).max() < TOL_MM
    second = next(m for m in prog.moves if m.index == 19)  # N90 (line 20)
    assert second.compensate and np.abs(second.start - [50.0, 40.0, 195.0]).max() < TOL_MM
    assert np.abs(second.end - [30.0, 30.0, 195.0]).max() < TOL_MM


def test_g53_with_g92_another_system_and_inch_units(tmp_path, tables):
    """G55 (Z -250), G92 Z10 at Z0 (offset -10), 'G20 G53 G0 Z-1.' (-25.4 mm): program Z = -25.4 + 250 + 10 =
    234.6; then 'G53 G0 X300 Y150': X = 300 - 260, Y = 150 - 150 (G92 on Z only)."""
    prog = _read(tmp_path, LINUXCNC, tables, "linuxcnc")
    assert np.abs(_end(prog, 5) - [5.0, 0.0, 234.6]).max() < TOL_MM
    assert np.abs(_end(prog, 7) - [40.0, 0.0, 2.0]).max() < TOL_MM


def test_without_a_work_offset_table_the_g53_position_is_refused_naming_the_option(tmp_path, tables):
    with pytest.raises(InputError) as e:
        _read(tmp_path, FUSION, None)
    msg = str(e.value)
    assert "line 10, column 8: 'X20.'" in msg and "line 6 moved Z in machine coordinates (G53)" in msg, msg
    assert "--work-offsets" in msg and len(msg) - len(str(tmp_path / "p.nc")) < 300
    out = tmp_path / "o"
    assert main(["compensate", str(tmp_path / "p.nc"), "--machine", "mill-xyz", "--model", str(_truth(tmp_path)),
                 "--method", "exact", "--out", str(out), "--dialect", "auto"]) != 0


def test_g53_under_g91_is_not_placed(tmp_path, tables):
    """LinuxCNC refuses G53 in incremental mode and Fanuc ignores it: the position is not carried."""
    with pytest.raises(InputError, match="it ran under G91 or G41/G42"):
        _read(tmp_path, "G21 G90 G54\nG0 X0 Y0 Z0\nG91 G53 G0 Z-5.\nG90 G1 X1 Y1 F100\nM2\n", tables)


def _truth(tmp_path):
    return ChainElementSet.random(load_machine("mill-xyz"), 101, ELEMENT_SCALE_UM, 11).save(tmp_path / "truth.json")


def _compensated(tmp_path, text, tables, dialect):
    prog = tmp_path / "fusion.nc"
    prog.write_text(text)
    truth, out = _truth(tmp_path), tmp_path / "o"
    assert main(["compensate", str(prog), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(out), "--dialect", dialect, "--work-offsets", str(tables[0]),
                 "--tool-table", str(tables[1])]) == 0
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    return prog, out / prog.name, truth


def test_a_fusion_program_with_g53_is_compensated_and_passes_the_independent_check(tmp_path, tables):
    """Every programmed point reproduced by the TRUE machine within 1 μm on its compensated axes, judged with frames
    the check reads itself (its G53 lines placed by its own patterns); the lines after the G53 hold Z at its machine
    value (no Z word written, as programmed) and their X Y words differ from the program's by the compensation only."""
    prog, written, truth = _compensated(tmp_path, FUSION, tables, "auto")
    verdict = independent_check(prog, written, "auto", truth, OFFSETS, TOOLS)
    assert verdict.startswith("ok: ") and float(verdict.split()[2]) <= TOL_POINT_UM, verdict
    assert "held at a G53 value" in verdict, verdict
    n40 = next(ln for ln in written.read_text().splitlines() if ln.startswith("N40 "))
    x = float(n40.split("X")[1].split()[0])
    assert "Z" not in n40 and abs(x - 20.0) < MAX_CORRECTION_MM and x != 20.0, n40


# Fusion 360 for Personal Use (Fanuc post), as its posts are worded: the retract to the top of the Z stroke in machine
# coordinates ("G53 G0 Z0."), then the positioning moves at that height as "high feed" G1 F5000. (no G0 in the
# personal-use posts) before the first G43; written for this project, not copied from a post's output
FUSION_TOP = """%
O2001 (FACE)
(Using high feed G1 F5000. instead of G0.)
N10 G90 G94 G17
N15 G21
N20 G53 G0 Z0.
N25 T1 M6
N30 S8000 M3
N35 G54
N40 G1 X15. Y5. F5000.
N45 X25. Y12.
N50 G0 G43 Z15. H1
N55 G1 Z-1. F400.
N60 X45.
N65 Y30.
N70 G0 Z15.
N75 G53 G0 Z0.
N80 M30
%
"""
HELD_AGREE_UM = 0.01
"""The model is the truth here: the error left along the held Z (the summary's, model) and the TRUE one the check
states differ by the change of the error over the X Y corrections only (μm/mm × tens of μm: far below this)."""


def test_z_held_at_the_top_of_its_stroke_by_g53_is_not_written_and_x_y_are_compensated(tmp_path, tables):
    """mill-xyz (Z stroke [-400, 0]) on a truth whose correction at machine Z 0 is +Z: a Z written as the program's
    plus its correction would be past the stroke (refused, naming --allow, before Z was held). Held: exit 0, N40 and
    N45 carry no Z word, X Y within 1 μm of every programmed point by the TRUE machine (independent check), the
    summary says 2 points held Z and the error left along it, which is the truth's Z error there."""
    mill = load_machine("mill-xyz")
    truth_els = ChainElementSet.load(_truth(tmp_path), mill)
    machine_points = np.array([[215.0, 105.0, 0.0], [225.0, 112.0, 0.0]])  # N40, N45: G54 + (X, Y), machine Z 0
    z_error_um = ChainField(mill, truth_els).predict(machine_points)[:, 2]
    assert (z_error_um < -TOL_POINT_UM).all(), z_error_um  # the correction is +Z: past the stroke if written
    prog, written, truth = _compensated(tmp_path, FUSION_TOP, tables, "auto")
    lines = written.read_text().splitlines()
    for n in ("N40 ", "N45 "):
        line = next(ln for ln in lines if ln.startswith(n))
        assert "Z" not in line and "X" in line and "Y" in line, line
    verdict = independent_check(prog, written, "auto", truth, OFFSETS, TOOLS)
    assert verdict.startswith("ok: ") and float(verdict.split()[2]) <= TOL_POINT_UM, verdict
    held_true_um = float(verdict.split("max ")[2].split()[0])
    e = json.loads((tmp_path / "o" / "compensate_summary.json").read_text())["files"][0]
    assert e["held"]["points"] == 2 and e["held"]["axes"] == ["Z"], e["held"]
    assert abs(e["held"]["along_held_max_um"] - np.abs(z_error_um).max()) < HELD_AGREE_UM, (e["held"], z_error_um)
    assert abs(held_true_um - e["held"]["along_held_max_um"]) < HELD_AGREE_UM + 0.005, verdict  # stated to 3 digits


# LinuxCNC's own rule (2.9 interp_arc.cc arc_data_ijk; G-code reference "Center Format Arcs"): radii that differ by
# 8 μm on a 1 mm radius (0.8 %) are within 2·0.01·√2 mm, so the controller runs the arc as a spiral
SPIRAL = "G21 G90 G54\nG0 X300 Y250 Z-10\nG1 Z-20 F300\nG2 X302 Y250 I1.004 J0\nG1 Y260\nM2\n"


def test_a_linuxcnc_spiral_arc_is_read_with_its_radius_linear_in_the_angle(tmp_path, tables):
    """posemath's circle (LinuxCNC's motion): radius = start radius + spiral · angle / total angle."""
    prog = _read(tmp_path, SPIRAL, tables, "linuxcnc")
    arc = next(m for m in prog.moves if m.index == 3)
    t = np.linspace(0.0, 1.0, 9)
    pts = move_points(arc, t)
    r = np.hypot(pts[:, 0] - 301.004, pts[:, 1] - 250.0)
    assert np.abs(r - (1.004 + t * (0.996 - 1.004))).max() < TOL_MM
    ang = np.unwrap(np.arctan2(pts[:, 1] - 250.0, pts[:, 0] - 301.004))
    assert np.abs(ang - (np.pi - t * np.pi)).max() < 1e-9  # G2 from 180° to 0° through 90° (clockwise: y > 250)
    assert pts[4, 1] > 250.0


def test_a_linuxcnc_spiral_arc_is_compensated_within_a_micrometre(tmp_path, tables):
    prog, written, truth = _compensated(tmp_path, SPIRAL, tables, "linuxcnc")
    verdict = independent_check(prog, written, "linuxcnc", truth, OFFSETS, TOOLS)
    assert verdict.startswith("ok: ") and float(verdict.split()[2]) <= TOL_POINT_UM, verdict


@pytest.mark.parametrize("text", ["G21 G90 G40 G54\nG1 X1 Y2 F100\n",
                                  "G21 G90 G49\nG53 G0 Z0\nG54 G40\nG1 X1 Y1 F100\n"])
def test_a_move_before_z_is_known_after_g40_or_g49_is_refused_not_crashed(tmp_path, text):
    """Events with no value (G40, G49) before the move: the refusal says why, no TypeError (LinuxCNC's
    plasmatest.ngc writes 'G90 G40' and never gives Z)."""
    with pytest.raises(InputError, match="no value yet for Z"):
        _read(tmp_path, text, None, "linuxcnc")


def test_x_y_held_by_g53_leave_a_plunge_compensated_in_z_alone(tmp_path, tables):
    """'G53 G0 X300 Y150' then 'G1 Z-10': X and Y held at their machine values (no X Y words on the plunge's
    lines), Z solved alone and the end point within 1 μm along Z by the TRUE machine (independent check); the
    summary says both axes were held."""
    text = "G21 G90 G54\nG0 X10 Y10 Z20\nG53 G0 X300 Y150\nG1 Z-10 F300\nG1 X20 Y20\nM2\n"
    prog, written, truth = _compensated(tmp_path, text, tables, "auto")
    e = json.loads((tmp_path / "o" / "compensate_summary.json").read_text())["files"][0]
    n = e["held"]["points"]  # the plunge's pieces (the planner splits it by the field)
    lines = written.read_text().splitlines()
    plunge = lines[3:3 + n]
    assert n >= 1 and all("Z" in ln and not any(w[0] in "XY" for w in ln.split()) for ln in plunge), plunge
    assert lines[3 + n].startswith("G1 X"), lines  # the next move, X and Y programmed again
    verdict = independent_check(prog, written, "auto", truth, OFFSETS, TOOLS)
    assert verdict.startswith("ok: ") and float(verdict.split()[2]) <= TOL_POINT_UM, verdict
    assert "held at a G53 value" in verdict, verdict
    assert e["held"]["axes"] == ["X", "Y"], e["held"]
