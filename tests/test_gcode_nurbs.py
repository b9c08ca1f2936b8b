"""LinuxCNC's NURBS blocks (compensation/gcode_spline.py: ``G5.2`` … ``G5.3``) read exactly or refused by name.

LinuxCNC G-code reference, "G5.2 G5.3 NURBS Block": between ``G5.2`` and ``G5.3`` the control points are given
with their weights ``P`` and the order ``L``; "the current coordinate, before the first G5.2 command, is always
taken as the first NURBS control point"; "to set the weight for this first control point, first program
G5.2 P- without giving any X Y"; the default order is 3. The curve is LinuxCNC's interpreter's: the clamped
uniform knot vector 0 (k times), 1 … n − k + 1, n − k + 2 (k times) and ``C(u) = Σ w_i N_i,k(u) P_i / Σ w_i
N_i,k(u)``. Here the basis is evaluated by its recursive definition, one knot span at a time (independently of
the reader's vectorised form); the compensated program is checked: every other line byte-identical, the
block's lines written as comments, every written chord vertex reached by the TRUE machine at the curve's point
within 1 μm, every chord within half the arc tolerance of the curve."""
import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.gcode_spline import spline_points
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups

WORK_MM = np.array([300.0, 200.0, -300.0])
"""G54 of the tests (mill-xyz)."""
Z_MM = -2.0
PROGRAM = ("G21 G90 G17\nG0 X10 Y10 Z5\nG1 Z-2 F300\nG5.2 P1.5 (the first control point's weight)\n"
           "G5.2 X30 Y60 P1 L4\n     X70 Y60 P2\n     X90 Y10 P1\n     X50 Y-20 P0.5\nG5.3\nG1 X0\nM2\n")
CTRL = [(10.0, 10.0), (30.0, 60.0), (70.0, 60.0), (90.0, 10.0), (50.0, -20.0)]
WEIGHTS = [1.5, 1.0, 2.0, 1.0, 0.5]
ORDER = 4
"""By hand from the manual's wording: the current point (10, 10) with the weight of 'G5.2 P1.5', then the four
G5.2 points; L4 (LinuxCNC takes an L greater than 3)."""
TOL_CURVE_MM = 1e-12
DENSE = 24
"""Curve points per chord for the deviation check."""
TOL_ARC_UM = 5.0
"""The run's --arc-tolerance-um (fewer chords: the test's own curve is evaluated point by point)."""


def _basis(i, k, u, t):
    """N_i,k(u) (u an array) by the recursive definition (a span [t_i, t_i+1) of order 1; the last non-empty
    span closed)."""
    if k == 1:
        last = t[i + 1] == t[-1] and t[i] < t[i + 1]
        return (((t[i] <= u) & (u < t[i + 1])) | (last & (u == t[-1]))).astype(float)
    out = np.zeros_like(u)
    if t[i + k - 1] != t[i]:
        out += (u - t[i]) / (t[i + k - 1] - t[i]) * _basis(i, k - 1, u, t)
    if t[i + k] != t[i + 1]:
        out += (t[i + k] - u) / (t[i + k] - t[i + 1]) * _basis(i + 1, k - 1, u, t)
    return out


def curve(ctrl, w, k, s):
    """The NURBS at fractions ``s`` (m,) of its parameter range, (m, 2) mm."""
    n = len(ctrl) - 1
    t = [0.0] * k + [float(v) for v in range(1, n - k + 2)] + [float(n - k + 2)] * k
    u = np.atleast_1d(np.asarray(s, dtype=float)) * (n - k + 2)
    b = np.stack([_basis(i, k, u, t) * w[i] for i in range(n + 1)], axis=1)
    return b @ np.asarray(ctrl) / b.sum(axis=1, keepdims=True)


def _read(text, tmp_path, dialect="linuxcnc"):
    p = tmp_path / "n.ngc"
    p.write_text(text)
    return p, parse_program(p, axis_words=AxisWords.of(load_machine("mill-xyz")), fast=False, dialect=dialect)


def test_the_block_is_one_move_on_linuxcncs_curve(tmp_path):
    _, prog = _read(PROGRAM, tmp_path)
    m = next(m for m in prog.moves if m.kind == "spline")
    assert m.index + 1 == 9 and m.arc["block"] == (3, 4, 5, 6, 7) and m.arc["order"] == ORDER
    assert np.allclose(m.arc["ctrl"], CTRL, atol=0) and list(m.arc["w"]) == WEIGHTS
    s = np.linspace(0.0, 1.0, 41)
    assert np.abs(spline_points(m.arc, s) - curve(CTRL, WEIGHTS, ORDER, s)).max() <= TOL_CURVE_MM
    assert np.abs(m.end - [50.0, -20.0, Z_MM]).max() == 0.0  # the last control point (the curve is clamped)


def test_a_nurbs_program_compensated_follows_the_curve(tmp_path):
    mill = load_machine("mill-xyz")
    truth = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    (tmp_path / "offsets.csv").write_text("system,x_mm,y_mm,z_mm\nG54,%g,%g,%g\n" % tuple(WORK_MM))
    src, _ = _read(PROGRAM, tmp_path)
    assert main(["compensate", str(src), "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--out", str(tmp_path / "out"), "--dialect", "linuxcnc", "--arc-tolerance-um",
                 str(TOL_ARC_UM), "--work-offsets", str(tmp_path / "offsets.csv")]) == 0
    out = parse_program(tmp_path / "out" / src.name, axis_words=AxisWords.of(mill), fast=False, dialect="linuxcnc")
    lines = PROGRAM.splitlines(keepends=True)
    groups = _groups(lines, out.lines)
    for i, g in enumerate(groups, start=1):
        if 4 <= i <= 8:  # the block's lines: comments (LinuxCNC would run the NURBS again)
            assert [out.lines[k] for k in g] == [f"(volcomp: NURBS control point, written as the chords below: "
                                                 f"{lines[i - 1].strip().replace('(', '[').replace(')', ']')})\n"]
        elif i not in (3, 9, 10):
            assert [out.lines[k] for k in g] == [lines[i - 1]]  # byte-identical
    g = groups[8]
    assert out.lines[g[0]].startswith("G1 X") and len(g) > 20
    ends = {m.index: m.end for m in out.moves}
    field = ChainField(mill, ChainElementSet.load(truth, mill))
    pts = curve(CTRL, WEIGHTS, ORDER, np.arange(1, len(g) + 1) / len(g))
    q = np.array([ends[k] for k in g]) + WORK_MM
    tip = mill.nominal(q) + field.predict(q) * 1e-3
    want = mill.nominal(np.c_[pts, np.full(len(g), Z_MM)] + WORK_MM)
    errs = np.linalg.norm(tip - want, axis=1) * 1e3
    assert errs.max() <= TOL_POINT_UM, errs.max()
    # the chords (the programmed points k/c) within half the arc tolerance of the curve, densely
    s = np.arange(len(g) + 1) / len(g)
    a, b = curve(CTRL, WEIGHTS, ORDER, s[:-1]), curve(CTRL, WEIGHTS, ORDER, s[1:])
    dense = curve(CTRL, WEIGHTS, ORDER, (s[:-1, None] + np.linspace(0, 1, DENSE)[None, :] / len(g)).ravel())
    dense = dense.reshape(len(g), DENSE, 2)
    d = (b - a)[:, None, :]
    lam = np.clip(((dense - a[:, None]) * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
    dev_um = np.linalg.norm(dense - (a[:, None] + lam[..., None] * d), axis=-1).max() * 1e3
    assert dev_um <= TOL_ARC_UM / 2, dev_um


PRE = "G21 G90 G17\nG0 X0 Y0 Z1\n"


@pytest.mark.parametrize("tail, line, col, says", [
    ("G5.2 X1 P1\nX2 Y2 P1\nX3 Y0 P1\nG5.3\nM2\n", 3, 6, "both X and Y"),
    ("G5.2 X1 Y1\nX2 Y2 P1\nX3 Y0 P1\nG5.3\nM2\n", 3, 6, "positive weight P"),
    ("G5.2 X1 Y1 P1\nP2\nX3 Y0 P1\nG5.3\nM2\n", 4, 1, "'P2' without X and Y"),
    ("G5.2 X1 Y1 P1 L4\nX2 Y2 P1\nG5.3\nM2\n", 5, 1, "order L = 4 needs"),
    ("G5.3\nM2\n", 3, 1, "without a G5.2 block"),
    ("G5.2 X1 Y1 P1\nG1 X2 Y2\nG5.3\nM2\n", 4, 4, "'X2' inside a NURBS block"),
    ("G91 G5.2 X1 Y1 P1\nX2 Y2 P1\nG5.3\nM2\n", 3, 10, "G91"),
    ("G5.2 X1 Y1 Z2 P1\nX2 Y2 P1\nG5.3\nM2\n", 3, 12, "'Z2' on a G5.2 line"),
])
def test_nurbs_blocks_not_interpretable_are_refused_by_name(tmp_path, tail, line, col, says):
    with pytest.raises(InputError) as err:
        _read(PRE + tail, tmp_path)
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'n.ngc'}: line {line}, column {col}: ") and says in msg, msg
    assert len(msg) - len(str(tmp_path)) < 300


@pytest.mark.parametrize("text, dialect, says", [
    (PRE + "G5.2 X1 Y1 P1\nX2 Y2 P1\nX3 Y0 P1\nG5.3\nM30\n", "fanuc", "'G5.2' (NURBS block (read with --dialect linuxcnc))"),
    (PRE + "G6.2 P1 K0 X1 Y1 R1 F100\nM30\n", "fanuc", "'G6.2' (NURBS block: not interpretable exactly"),
    (PRE + "G6.2 P1 K0 X1 Y1 R1 F100\nM2\n", "linuxcnc", "'G6.2' (NURBS block: not interpretable exactly"),
])
def test_other_nurbs_words_are_refused_by_name_and_why(tmp_path, text, dialect, says):
    with pytest.raises(InputError) as err:
        _read(text, tmp_path, dialect)
    assert str(err.value).startswith(f"{tmp_path / 'n.ngc'}: line 3, column 1: {says}"), str(err.value)
