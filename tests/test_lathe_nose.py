"""Tool nose radius compensation on a lathe (compensation/gcode_state.py, gcode_classify.py, nc_state.py, turning.py).

From the manuals' wording: on a Fanuc or Haas lathe (Fanuc 0i-TF "Tool nose radius compensation", Haas lathe
operator's manual "Tool Nose Compensation") ``G41``/``G42`` take the nose radius (and the imaginary tool tip) of the
offset register the ``TttOO`` word selected, not a D word; ``G40`` cancels. A lathe tool table here is
``tool,x_mm,z_mm[,radius_mm]``, a row per register. The path is compensated as programmed and the error the nose
compensation leaves is bounded by the field's gradient × the arm between the axes' point (the imaginary tip) and
the contour, at most (1 + √2)·r. LinuxCNC lathes keep LinuxCNC's rule (``G41 Dn``: tool n's radius; a bare
``G41``: the loaded tool's). Every program here is written from that wording, not copied; the frames are checked
against the program's own words read by patterns (not by the reader)."""
import json
import re

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import machine_with_lathe_tool, program_frames, read_tool_table, read_work_offsets
from compensation.turning import NOSE_ARM, TURN_SAMPLES
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM

LATHE = "lathe-xzc"
XZ = AxisWords(LATHE, ("X", "Z"), ())
TOOLS = {1: (-40.0, 120.0, 0.8), 2: (25.0, 80.0, 0.4)}
"""Offset register -> (X, Z offset mm, nose radius mm)."""
CSV = "tool,x_mm,z_mm,radius_mm\n" + "".join(f"{t},{x:g},{z:g},{r:g}\n" for t, (x, z, r) in TOOLS.items())
WORK_Z_MM = 300.0
PROGRAM = """O0001 (finish turning with nose radius compensation)
G18 G21 G40 G54
T0101
G0 X70. Z5.
S800 M3
G42 G1 X60. Z0. F0.2
G1 Z-30.
G40 G0 X80. Z5.
T0202
G0 X55. Z5.
G41 G1 X50. Z0. F0.15
G1 Z-20.
G2 X60. Z-25. R5.
G1 X70.
G40 G0 X90. Z10.
M5
M30
"""
MAX_MESSAGE = 300
ELEMENT_SCALE_UM = 10.0
TOL_GRADIENT_REL = 0.01
"""Central differences of 0.5 mm vs the analytic Jacobian of the cubic-spline elements: within 1 %."""


def _radius_by_hand(lines):
    """Per source line, from the program's words by pattern: the nose radius in force (NaN: G40)."""
    reg, on, out = None, False, []
    for ln in lines:
        m = re.search(r"T\d\d(\d\d)", ln)
        reg = int(m.group(1)) if m else reg
        on = bool(re.search(r"G4[12]\b", ln)) or (on and "G40" not in ln)
        out.append(TOOLS[reg][2] if on else np.nan)
    return out


def _parse(tmp_path, text, dialect="fanuc", name="p.nc"):
    p = tmp_path / name
    p.write_text(text)
    return p, parse_program(p, axis_words=XZ, dialect=dialect, lathe_x="diameter")


def _frames(tmp_path, prog, tools=CSV):
    (tmp_path / "t.csv").write_text(tools)
    return program_frames(prog, read_work_offsets("machine"), read_tool_table(tmp_path / "t.csv"))


@pytest.mark.parametrize("dialect", ["fanuc", "haas"])
def test_g41_g42_take_the_t_words_register_radius(tmp_path, dialect):
    _, prog = _parse(tmp_path, PROGRAM, dialect)
    frames = _frames(tmp_path, prog)
    want = _radius_by_hand(PROGRAM.splitlines())
    got = frames.radius([m.index for m in prog.moves])
    assert np.array_equal(got, [want[m.index] for m in prog.moves], equal_nan=True)
    assert np.isfinite(got).sum() == 6 and set(got[np.isfinite(got)]) == {0.8, 0.4}


def _refusal(tmp_path, text, dialect="fanuc", tools=CSV, at_frames=False):
    with pytest.raises(InputError) as err:
        p, prog = _parse(tmp_path, text, dialect)
        if at_frames:
            _frames(tmp_path, prog, tools)
    msg = str(err.value)
    assert len(msg) - len(str(tmp_path)) < MAX_MESSAGE, msg
    return msg


def test_a_register_without_a_radius_is_refused_naming_the_column(tmp_path):
    msg = _refusal(tmp_path, PROGRAM, tools="tool,x_mm,z_mm\n1,-40,120\n2,25,80\n", at_frames=True)
    assert f"{tmp_path / 'p.nc'}: line 6, column 1: 'G42 (T offset 01)': the nose radius of offset register 01 is " \
           "not known: the tool table's radius_mm column gives it (--tool-table, row tool 1)" == msg, msg


@pytest.mark.parametrize("text, dialect, where", [
    (PROGRAM.replace("T0101\n", ""), "fanuc", "line 5, column 1: 'G42' takes the nose radius of the T word's offset "
                                               "register (TttOO), and no register is in force"),
    (PROGRAM.replace("T0101\n", "T0100\n"), "haas", "line 6, column 1: 'G42' takes the nose radius"),
    (PROGRAM.replace("G42 G1", "G42 D1 G1"), "fanuc", "line 6, column 5: 'D1' on a fanuc lathe: G41/G42 take the "
                                                       "nose radius of the T word's offset register"),
    (PROGRAM.replace("G1 Z-30.", "D2"), "haas", "line 7, column 1: 'D2' on a haas lathe"),
    (PROGRAM.replace("G1 Z-30.", "T0202 G1 Z-30."), "fanuc", "line 7, column 1: a T word changing the offset "
                                                             "register while G42 is in force"),
    (PROGRAM.replace("T0101\n", ""), None, "line 5, column 1: 'G42' without D (the current tool's radius): write 'G42 "
                                           "Dn' with the tool table's number n; on a Fanuc or Haas lathe the TttOO "
                                           "word's register gives it: name the controller with --dialect"),
])
def test_what_the_manuals_do_not_settle_is_refused(tmp_path, text, dialect, where):
    assert where in _refusal(tmp_path, text, dialect)


def test_the_same_register_again_and_a_change_after_g40_are_read(tmp_path):
    text = PROGRAM.replace("G1 Z-30.", "T0101 G1 Z-30.").replace("G40 G0 X80. Z5.\nT0202", "G40 G0 X80. Z5. T0202")
    _, prog = _parse(tmp_path, text)
    got = _frames(tmp_path, prog).radius([m.index for m in prog.moves])
    assert np.array_equal(got, [_radius_by_hand(text.splitlines())[m.index] for m in prog.moves], equal_nan=True)


@pytest.mark.parametrize("dialect, lathe, what", [
    ("haas", True, "line 4, column 1: the G71 on line 3 names its contour's first block N10: that block must "
                   "follow the cycle line"),  # read by compensation.nc_contour: tests/test_lathe_contour_cycles.py
    ("fanuc", True, "line 4, column 1: the G71 on line 3 names its contour's first block N10"),
    ("linuxcnc", True, "line 3, column 5: 'P10' on a G71 line: only Q X Z D I R are read there"),  # nc_g7x
    ("haas", False, "'G71' on a haas mill: bolt hole arc: a hole pattern whose positions the control computes"),
])
def test_g71_is_refused_saying_why_in_that_dialect(tmp_path, dialect, lathe, what):
    p = tmp_path / "g71.nc"
    body = "G71 P10 Q20 U0.5 W0.1 D1.0 F0.2\n" if lathe else "G71 I10. J0. K30. L4\n"
    p.write_text(("G18 G21\nG0 X60. Z10.\n" if lathe else "G21 G90\nG0 X0 Y0 Z10\n") + body + "M30\n")
    ax = XZ if lathe else AxisWords.of(load_machine("mill-xyz"))
    with pytest.raises(InputError) as err:
        parse_program(p, axis_words=ax, dialect=dialect, lathe_x="diameter" if dialect != "linuxcnc" else None)
    msg = str(err.value)
    assert what in msg and "no dialect here says which" not in msg and len(msg) - len(str(tmp_path)) < MAX_MESSAGE, msg


LINUXCNC = "G18 G21 G90 G8\nT1 M6 G43\nG0 X35 Z5\nG42 D2 G1 X30 Z0 F0.2\nG1 Z-20\nG40 G0 X40\nG41 G1 X30 Z-25\n" \
           "G1 Z-30\nG40 G0 X45\nM30\n"
"""LinuxCNC: ``G42 D2`` takes tool 2's radius; a bare ``G41`` the loaded tool's (tool 1)."""


def test_a_linuxcnc_lathe_keeps_d_and_the_loaded_tool(tmp_path):
    p = tmp_path / "l.ngc"
    p.write_text(LINUXCNC)
    prog = parse_program(p, axis_words=XZ, dialect="linuxcnc")
    got = _frames(tmp_path, prog).radius([m.index for m in prog.moves])
    want = {2: np.nan, 3: 0.4, 4: 0.4, 5: np.nan, 6: 0.8, 7: 0.8, 8: np.nan}  # 0-based line: radius
    assert np.array_equal(got, [want[m.index] for m in prog.moves], equal_nan=True)


def test_a_fanuc_lathe_program_is_compensated_and_the_nose_bound_reported(tmp_path, capsys):
    """Compensated on lathe-xzc against a simulated truth: the TRUE residual over the turn within 1 μm; the bound is
    at least the field's gradient along X and Z at the programmed end points under G41/G42 (the analytic Jacobian,
    independently, over the turn, at each register's tool offsets) × (1 + √2) × the nose radius."""
    lathe = load_machine(LATHE)
    els = ChainElementSet.random(lathe, 101, ELEMENT_SCALE_UM, 11)
    truth = els.save(tmp_path / "truth.json")
    p = tmp_path / "p.nc"
    p.write_text(PROGRAM)
    (tmp_path / "t.csv").write_text(CSV)
    (tmp_path / "o.csv").write_text(f"system,x_mm,y_mm,z_mm\nG54,0,0,{WORK_Z_MM}\n")
    out = tmp_path / "out"
    assert main(["compensate", str(p), "--machine", LATHE, "--model", str(truth), "--truth", str(truth), "--method",
                 "exact", "--dialect", "fanuc", "--lathe-x", "diameter", "--work-offsets", str(tmp_path / "o.csv"),
                 "--tool-table", str(tmp_path / "t.csv"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["turning"]["true"]["max_um"] <= TOL_POINT_UM < e["turning"]["true_uncompensated"]["max_um"]
    ends = {1: [(30.0, 0.0), (30.0, -30.0)], 2: [(25.0, 0.0), (25.0, -20.0), (30.0, -25.0), (35.0, -25.0)]}
    lin = [j for j, a in enumerate(lathe.axes) if a.kind == "linear"]
    at_ends = 0.0
    for reg, pts in ends.items():
        x, z, r = TOOLS[reg]
        q = np.array([(px + x, pz + WORK_Z_MM + z, c) for px, pz in pts
                      for c in np.arange(TURN_SAMPLES) * 360.0 / TURN_SAMPLES])
        J = ChainField(machine_with_lathe_tool(lathe, x, z), els).jacobian(q)[:, :, lin]
        at_ends = max(at_ends, float((np.linalg.norm(J, ord=2, axis=(1, 2)) * NOSE_ARM * r).max()))
    assert at_ends * (1 - TOL_GRADIENT_REL) <= e["cutter_radius_bound_um"] and at_ends > 0.1
    assert "(1 + sqrt 2) x nose radius" in printed and e["cutter_radius_arm"].startswith("(1 + sqrt 2)")
