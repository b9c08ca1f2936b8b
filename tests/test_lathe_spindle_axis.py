"""A lathe program's points on the spindle axis (X0: centre drilling, drilling, facing to the centre) are written where
the tool tip passes nearest the axis, not refused (compensation/turning.py ``unreachable_radius``): the tip passes its
centre-height error h off the plane through the axis in which X moves it, which no X and Z remove.

Checked on ``lathe-xzc`` with the seeded truth of tests/test_lathe_g33.py (also the model, ``--method exact``),
independently of the compensator's closest approach: every other programmed point reached within
:data:`TOL_POINT_UM`; on the axis the TRUE mean radius left is the centre height plus the tip's wobble along the slide
over the turn (:func:`_wobble_bound`), and no X of a scan brings the tip nearer the axis; the corpus check
(``lathe_points_reached``) finds each on-axis point within the tolerance of the least radius any X reaches; the
summary, the console and the written program's header say so; a real non-convergence elsewhere is still refused."""
import json
import re

import numpy as np

from benchmarks.suite.gcode_checks import lathe_points_reached
from compensation.turning import _tip_over_turn, height_um, surface_residual_um
from test_lathe_g33 import PART_Z_MM, TOL_POINT_UM, _compensate, _field, _read

FACE_AND_DRILL = ("G21 G18 G90 G7\nG54\nS800 M3\nG0 X42 Z2\nG1 Z0 F100\nX0\nG0 Z2\nX0\nG1 Z-10 F50\nG0 Z2\nX60\nM5\n"
                  "M2\n")
"""Facing to the centre (line 6 ends on the axis) and drilling on it (line 9), diameter mode."""
AXIS_LINES = [6, 9]
AXIS_Z_MM = [0.0, -4.0, -10.0]
"""The programmed points on the axis (work Z): line 6's end, line 9's half-way point and end (written in two pieces,
--max-segment-mm)."""
HEIGHT_SLOPE_UM = 1e-6
"""The tip's mean radius is at least its centre height (at every angle |P| ≥ its distance from the slide's plane);
this absorbs rounding."""
NEAREST_UM = 0.05
"""No X of the scan brings the tip nearer the axis than the written X by more than this: the crossing is the least
mean radius up to second order in the tip's wobble (tests/test_turning.py, observed 0.003 um)."""
WRITTEN_UM = 1e-6
"""The summary's centre height is the model's (here the truth) at the written X and Z, which the program rounds to
1 nm: the height changes by the error's slope (nm per um) times that."""
AXIS_SCAN_UM = np.arange(-150.0, 150.01, 0.5)
"""X offsets (um) about the written X: wider than the truth's error there (tens of um)."""


def _place(moves):
    return np.array([[m.end[0], m.end[1] + PART_Z_MM, 0.0] for m in moves])


def _wobble_bound(field, lathe, q):
    """(n,) um: the mean over the turn of s²/(2|c|) at ``q`` (n, 3), the tip's offset along the slide s (its mean
    removed) and across it c: |P| = √(c² + s²) ≤ |c| + s²/(2|c|), so the mean radius at the crossing is at most
    the centre height plus this."""
    P, u = _tip_over_turn(field, lathe, q)
    c = np.abs(u[..., 0] * P[..., 1] - u[..., 1] * P[..., 0]) * 1e3
    s = (u * P[..., :2]).sum(axis=2) * 1e3
    s -= s.mean(axis=1, keepdims=True)
    return (s ** 2 / (2.0 * c)).mean(axis=1)


def test_points_on_the_spindle_axis_are_written_at_the_closest_approach(tmp_path, capsys):
    rc, src, dst, truth = _compensate(tmp_path, FACE_AND_DRILL)
    printed = capsys.readouterr().out
    assert rc == 0
    out = dst.read_text().splitlines()
    head = [ln for ln in out if ln.startswith("(volcomp:")]
    body = [ln for ln in out if not ln.startswith("(volcomp:")]
    assert len(head) == 1 and out[0] == head[0] and len(head[0]) <= 250  # one header line, a LinuxCNC line's length
    assert "on the spindle axis [line[s] 6, 9]" in head[0] and "adjust the tool's centre height" in head[0]
    src_lines = FACE_AND_DRILL.splitlines()
    assert len(body) == len(src_lines) + 2  # lines 6 and 9 each written as two pieces (--max-segment-mm)
    entry = json.loads((tmp_path / "out" / "compensate_summary.json").read_text())["files"][0]
    axis = entry["spindle_axis_points"]
    assert entry["failures"] == 0 and entry["guard_violations"]["convergence"] == 0
    assert axis["count"] == 3 and axis["lines"] == AXIS_LINES and "centre height" in axis["why"]
    assert axis["model_max_here"] and axis["residual_max_um"] == entry["model_max_um"]  # the largest is there
    assert "3 point(s) on the spindle axis (line(s) 6, 9), not failures" in printed

    lathe, field = _field(truth)
    p_src, p_out = _read(src), _read(dst)
    m_src = [m for m in p_src.moves if m.compensate]
    m_out = [m for m in p_out.moves if m.compensate]
    on_axis = []
    errs, missed = lathe_points_reached(field, lathe, m_src, m_out, (0.0, PART_Z_MM), TOL_POINT_UM, on_axis)
    assert missed is None and len(errs) == len(m_src) and max(errs) <= TOL_POINT_UM  # off the axis: reached
    assert [line for line, _ in on_axis] == [6, 9]  # on it: within the tolerance of the least radius any X reaches

    ends = [m for m in m_out if abs(m.end[0]) < 0.1]  # the written moves that end at the axis
    assert len(ends) == axis["count"]
    q = _place(ends)
    programmed = np.array([[0.0, z + PART_Z_MM, 0.0] for z in AXIS_Z_MM])
    mean, _ = surface_residual_um(field, lathe, q, programmed)
    h = height_um(field, lathe, q)
    assert np.all(mean[:, 0] >= h - HEIGHT_SLOPE_UM) and np.all(mean[:, 0] <= h + _wobble_bound(field, lathe, q))
    assert np.abs(mean[:, 1]).max() <= TOL_POINT_UM  # Z reached
    assert abs(h.max() - axis["height_max_um"]) <= WRITTEN_UM and h.min() > 1.0  # the summary's height (TRUE=model)
    for row, target, at in zip(q, programmed, mean[:, 0]):
        scan = np.repeat(row[None], len(AXIS_SCAN_UM), axis=0)
        scan[:, 0] += AXIS_SCAN_UM * 1e-3
        radius = surface_residual_um(field, lathe, scan, np.repeat(target[None], len(scan), axis=0))[0][:, 0]
        assert at <= radius.min() + NEAREST_UM  # no X brings the tip nearer the axis


def test_a_real_non_convergence_elsewhere_is_still_refused(tmp_path, capsys, monkeypatch):
    """The turning solve reported unconverged at every point off the axis: those are refused by the convergence guard
    as before, the points on the axis are not among them."""
    import compensation.turning as turning
    solve = turning.solve_turning

    def failing(field, machine, axes_d, ball_um, **kw):
        q, res, conv, spread, it = solve(field, machine, axes_d, ball_um, **kw)
        return q, res, conv & (np.abs(axes_d[:, 0]) < 1e-9), spread, it
    monkeypatch.setattr(turning, "solve_turning", failing)
    rc, _, dst, _ = _compensate(tmp_path, FACE_AND_DRILL)
    err = capsys.readouterr().err
    assert rc != 0 and not dst.exists() and "refused by guard(s) convergence" in err
    listed = re.findall(r"point \d+ \(line (\d+)\): convergence: exact did not converge", err)
    assert sorted(set(map(int, listed))) == [5, 6] and len(listed) == 2  # line 5's end, line 6's half-way point



def test_an_unconverged_closest_approach_is_refused(tmp_path, capsys, monkeypatch):
    """Where the closest approach itself does not converge the point is no spindle-axis point but a solver failure:
    refused by the convergence guard, the on-axis lines named."""
    import compensation.turning as turning
    nearest = turning._closest_approach
    monkeypatch.setattr(turning, "_closest_approach",
                        lambda *a, **kw: (nearest(*a, **kw)[0], np.zeros(len(a[2]), dtype=bool)))
    rc, _, dst, _ = _compensate(tmp_path, FACE_AND_DRILL)
    err = capsys.readouterr().err
    assert rc != 0 and not dst.exists() and "refused by guard(s) convergence" in err
    listed = re.findall(r"point \d+ \(line (\d+)\): convergence: exact did not converge", err)
    assert sorted(map(int, listed)) == [6, 9, 9]

TOOL_PROGRAM = ("G18 G21 G90 G8\nT2 M6\nG43 H2\nS800 M3\nG0 X10 Z2\nG1 Z0 F50\nX0\nG0 Z2\nG49\nG0 X20\nG1 Z-1\nX0\n"
                "G0 Z2\nM5\nM2\n")
"""Facing to the centre at tool 2's offset (G43 H2: the count's table, 100 mm along Z) and again with none (G49)."""
SHIFT_MM = 0.002
"""A written word moved by 2 um: X off the axis, Z on it (each 2 um of error, first order; on the axis an X shift
moves the radius only to second order, √(h² + d²) − h, which the check rightly accepts)."""


def test_the_corpus_check_follows_tool_offsets_and_the_axis(tmp_path):
    """``lathe_check`` (benchmarks/suite/gcode_checks.py) on a compensated program with a tool offset and points on the
    axis: ok, each on-axis point named; a written word moved by :data:`SHIFT_MM` off or on the axis: WRONG."""
    from benchmarks.suite.gcode_checks import lathe_check
    from benchmarks.suite.gcode_corpus import _tables
    from compensation.app.cli import main
    from compensation.nc_state import read_tool_table, read_work_offsets
    from errormap.chain_elements import ChainElementSet
    from errormap.io import InputError
    from errormap.machine import load_machine
    _tables(tmp_path, read_work_offsets, read_tool_table, InputError)
    truth = ChainElementSet.random(load_machine("lathe-xzc"), 101, 10.0, 11).save(tmp_path / "truth.json")
    src = tmp_path / "p.ngc"
    src.write_text(TOOL_PROGRAM)
    assert main(["compensate", str(src), "--machine", "lathe-xzc", "--model", str(truth), "--truth", str(truth),
                 "--method", "exact", "--dialect", "linuxcnc", "--out", str(tmp_path / "o"), "--work-offsets",
                 str(tmp_path / "offsets-lathe-xzc.csv"), "--tool-table", str(tmp_path / "tools.csv")]) == 0
    out = tmp_path / "o" / "p.ngc"
    verdict = lathe_check(src, out, "linuxcnc", truth)
    assert verdict.startswith("ok: ") and "(2 on the spindle axis" in verdict
    body = out.read_text().splitlines(keepends=True)
    k6 = next(i for i, ln in enumerate(body) if ln.startswith("G1 Z"))  # line 6: ends at X10 (radius, G8)
    k7 = body.index("G0 Z2\n", k6) - 1  # line 7's last piece: ends on the axis
    assert abs(float(re.search(r"X(-?[\d.]+)", body[k7]).group(1))) < 0.1
    for line, k, word in ((6, k6, "X"), (7, k7, "Z")):
        moved = list(body)
        w = re.search(word + r"(-?[\d.]+)", moved[k])
        moved[k] = moved[k].replace(w.group(0), f"{word}{float(w.group(1)) + SHIFT_MM:.6f}")
        bad = tmp_path / f"bad{line}.ngc"
        bad.write_text("".join(moved))
        assert lathe_check(src, bad, "linuxcnc", truth).startswith(f"WRONG: line {line} ")
