"""LinuxCNC's splines (compensation/gcode_spline.py): ``G5`` cubic (I J P Q; continued without I J) and
``G5.1`` quadratic (I J), read exactly under ``--dialect linuxcnc``, compensated on mill-xyz by sampling
the exact curve and written as compensated G1 moves. Checked independently: the control points here are
derived by hand from the LinuxCNC G-code reference's definitions and the curve evaluated by de Casteljau's
construction (the reader uses the Bernstein form); every written vertex run on the TRUE machine reaches
the curve's point at its parameter within 1 μm; the chords stay within half the arc tolerance of the
curve; every other line byte-identical (tests/program_checks.py)."""
import json
from pathlib import Path

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.gcode import AxisWords, parse_program
from compensation.nc_state import machine_with_tool
from compensation.pathio import DEFAULT_ARC_TOLERANCE_UM
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.io import InputError
from errormap.machine import load_machine
from program_checks import TOL_POINT_UM, _groups, true_point_errors_um

DATA = Path(__file__).resolve().parent / "data"
PROG = DATA / "dialects" / "linuxcnc_splines.ngc"
OFFSETS = DATA / "controller" / "offsets.csv"
TOOLS = DATA / "controller" / "tools.csv"
G59_1_MM = np.array([150.0, 50.0, -200.0])
"""The G59.1 row of offsets.csv."""
TOOL2_MM = 100.0
"""Tool 2's length in tools.csv (G43 H2)."""
Z_MM = -40.0
"""The program's cutting depth (N10 G1 Z-40)."""
CONTROL_MM = {  # 0-based line: control points in part coordinates, by hand from the manual's definitions
    9: [(0, 0), (0, 30), (10, -20), (10, 10)],      # N20 G5 I0 J30 P0 Q-30 X10 Y10: P1 = P0+(I,J), P2 = end+(P,Q)
    10: [(10, 10), (10, 40), (20, -10), (20, 20)],  # N30 G5 P0 Q-30 X20 Y20: P1 = P0 − (previous P, Q)
    11: [(20, 20), (20, 50), (30, 0), (30, 30)],    # N40 (modal G5)
    13: [(40, 40), (15, -35), (0, 40)],             # N60 G5.1 X0 I-25 J-75 (Y stays 40)
    14: [(0, 40), (0, 30), (-10, 30)],              # N70 G91 G5.1 X-10 Y-10 J-10 (end incremental, I 0)
}
DENSE = 400
"""Curve samples per chord for the deviation check (the chord deviation varies by ≪ 1 % between them)."""


def _casteljau(ctrl, t) -> np.ndarray:
    """The curve at parameters ``t`` (m,) by repeated linear interpolation, (m, 2) mm."""
    t = np.asarray(t, float)[:, None]
    p = [np.asarray(c, float)[None, :] for c in ctrl]
    while len(p) > 1:
        p = [(1 - t) * a + t * b for a, b in zip(p[:-1], p[1:])]
    return p[0]


def _chord_deviation_mm(ctrl, ts) -> float:
    """Largest distance of the curve from its chords between parameters ``ts`` (c + 1,), :data:`DENSE`
    curve points per chord."""
    a, b = ts[:-1, None], ts[1:, None]
    s = np.linspace(0.0, 1.0, DENSE)[None, :]
    pts = _casteljau(ctrl, (a + (b - a) * s).ravel()).reshape(len(a), DENSE, 2)
    A, B = _casteljau(ctrl, ts[:-1])[:, None, :], _casteljau(ctrl, ts[1:])[:, None, :]
    d = B - A
    u = np.clip(((pts - A) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(pts - (A + u[..., None] * d), axis=-1).max())


@pytest.fixture(scope="module")
def mill():
    return load_machine("mill-xyz")


@pytest.fixture()
def run(tmp_path, mill, capsys):
    truth_file = ChainElementSet.random(mill, 101, 10.0, 11).save(tmp_path / "truth.json")
    out = tmp_path / "o"
    assert main(["compensate", str(PROG), "--machine", "mill-xyz", "--model", str(truth_file), "--method", "exact",
                 "--out", str(out), "--truth", str(truth_file), "--dialect", "linuxcnc", "--work-offsets",
                 str(OFFSETS), "--tool-table", str(TOOLS)]) == 0
    return out, truth_file, capsys.readouterr().out


def test_splines_every_sampled_point_reached_by_the_true_machine(run, mill):
    out, truth_file, printed = run
    e = json.loads((out / "compensate_summary.json").read_text())["files"][0]
    assert e["spline_lines"] == [k + 1 for k in CONTROL_MM]
    assert "written as compensated G1 moves" in printed
    truth_els = ChainElementSet.load(truth_file, mill)
    # end points and byte-identical non-motion lines: the shared independent check
    errs = true_point_errors_um(PROG, out / PROG.name, mill, truth_els, {"G59.1": G59_1_MM}, {2: TOOL2_MM},
                                dialect="linuxcnc")
    assert errs.max() < TOL_POINT_UM
    # every sampled point: written vertex k of c (+ G59.1, tool 2 on the TRUE machine) on the curve at k/c
    aw = AxisWords.of(mill)
    src = parse_program(PROG, axis_words=aw, fast=False, dialect="linuxcnc").lines
    p_out = parse_program(out / PROG.name, axis_words=aw, fast=False, dialect="linuxcnc")
    ends = {m.index: m.end for m in p_out.moves}
    mt = machine_with_tool(mill, TOOL2_MM)
    truth = ChainField(mt, truth_els)
    shift = G59_1_MM + [0.0, 0.0, TOOL2_MM]
    groups = _groups(src, p_out.lines)
    worst, n = 0.0, 0
    for i, ctrl in CONTROL_MM.items():
        g = groups[i]
        assert p_out.lines[g[0]].lstrip().startswith("N") and " G1 " in p_out.lines[g[0]]
        assert not any(w in p_out.lines[k].split("(")[0] for k in g for w in ("G5", " I", " J", " P", " Q"))
        for k, line in enumerate(g, start=1):
            q = ends[line] + shift
            tip = mt.nominal(q[None])[0] + truth.predict(q[None])[0] * 1e-3
            target = mt.nominal((np.r_[_casteljau(ctrl, [k / len(g)])[0], Z_MM] + shift)[None])[0]
            worst, n = max(worst, float(np.linalg.norm(tip - target) * 1e3)), n + 1
    assert n > 50 and worst < TOL_POINT_UM


@pytest.mark.parametrize("tol_um", [DEFAULT_ARC_TOLERANCE_UM, 5.0])
def test_chords_within_the_arc_tolerance_of_the_exact_curve(mill, tol_um):
    """The planner's chords (vertices at k/c, :func:`compensation.chain_gcode.plan_chain_gcode`) against the exact
    curve sampled densely: every curve point within ``tol_um`` of its chord (the whole arc tolerance, as for
    arcs)."""
    from compensation.chain_gcode import plan_chain_gcode
    prog = parse_program(PROG, axis_words=AxisWords.of(mill), fast=False, dialect="linuxcnc")
    job = plan_chain_gcode(prog, tol_um, max_segment_mm=None)
    comp = [m for m in prog.moves if m.compensate]
    for m, c in zip(comp, job.counts):
        if m.kind != "spline":
            continue
        dev = _chord_deviation_mm(CONTROL_MM[m.index], np.arange(c + 1) / c)
        assert dev * 1e3 <= tol_um, (m.index, dev * 1e3)
        assert c > 1


PRELUDE = "G21 G90 G17\nG0 X0 Y0 Z0\nG1 Z-1 F100\n"
REFUSED = [  # program tail, dialect, what the message must name
    ("G5 I0 J3 P0 Q-3 X1 Y1\n", None, "--dialect"),
    ("G5 P0 Q-3 X1 Y1\n", "linuxcnc", "without I and J"),
    ("G5 I0 J3 P0 X1 Y1\n", "linuxcnc", "without Q"),
    ("G5 I1 P0 Q-3 X1 Y1\n", "linuxcnc", "I and J both, or neither"),
    ("G5 I0 J3 P0 Q-3 X1 Y1 Z-2\n", "linuxcnc", "X and Y only"),
    ("G18\nG5 I0 J3 P0 Q-3 X1 Y1\n", "linuxcnc", "G17 XY only"),
    ("G5.1 X2 I0 J0\n", "linuxcnc", "non-zero I or J"),
    ("G5.1 X2 I1 J1 P2\n", "linuxcnc", "'P2' on a G5.1 line"),
    ("G5 I0 J3 P0 Q-3 X1 Y1\nG1 X2\nG5 P0 Q-3 X3 Y1\n", "linuxcnc", "without I and J"),
    ("G5 I0 J3 P0 Q-3 X1 Y1\nG28\nG5 P0 Q-3 X3 Y1\n", "linuxcnc", "before X and Y are known"),
]


@pytest.mark.parametrize("tail, dialect, says", REFUSED)
def test_splines_not_interpretable_are_refused_by_name(tmp_path, mill, tail, dialect, says):
    p = tmp_path / "s.ngc"
    p.write_text(PRELUDE + tail)
    with pytest.raises(InputError) as ei:
        parse_program(p, axis_words=AxisWords.of(mill), fast=False, dialect=dialect)
    msg = str(ei.value)
    assert says in msg and "line" in msg and "column" in msg and len(msg) < 300 and "Traceback" not in msg
