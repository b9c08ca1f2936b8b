"""A linearised, compensated arc stays within the chord tolerance of the true arc.

The error field is the simulated truth itself (the chain field of ``make_chain_truth``), so the
machine driven with the written commands reaches ``forward(q) + E(q)``: the TRUE residual.
It is sampled densely along every written chord (what the controller interpolates: linear
in the axes between consecutive vertices), not only at the vertices, and measured as the
distance to the nominal arc in the WCS. Last, a Fanuc program's arcs whose start and end radii differ: read
within a rounding, refused beyond it with the controller's rule named.
"""
import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.suite.gcode_checks import independent_check
from benchmarks.suite.gcode_corpus import STYLE_TABLES, style_tables
from benchmarks.suite.toolpath import TruthField
from compensation.app.cli import main
from compensation.nc_state import MACHINE, read_work_offsets
from compensation.solvers import solve
from errormap.chain_elements import ChainElementSet
from errormap.chain_field import ChainField
from errormap.chain_kernel import forward
from errormap.chain_truth import make_chain_truth
from errormap.machine import load_machine
from path_files import read_as_compensate
from program_checks import TOL_POINT_UM

MCS = read_work_offsets(MACHINE)
"""The G-code programs here are written in machine coordinates (the grinder's axes): read with
--work-offsets machine (a program is never read at an assumed zero)."""

ARC_TOL_UM = 0.5           # the default --arc-tolerance-um, the promise under test
ROUNDING_UM = 0.002        # the writer's 6 decimals (0.5 nm per axis) and the solver's 1e-4 μm
SAMPLES_PER_CHORD = 40


def _distance_to_arc_um(machine, points_mm, centre_xz, radius_mm, a_deg):
    """Distance (μm) of WCS points to the nominal circle of centre (x, z) and radius in the XZ
    plane of the axes at fixed A (in the WCS a circle in the plane spanned by px and the radial
    direction of A)."""
    c = forward(machine, np.array([[centre_xz[0], centre_xz[1], a_deg]]))[0]
    radial = forward(machine, np.array([[centre_xz[0], centre_xz[1] + 1.0, a_deg]]))[0] - c
    axial = forward(machine, np.array([[centre_xz[0] + 1.0, centre_xz[1], a_deg]]))[0] - c
    d = points_mm - c
    u, w = d @ axial, d @ radial
    off = d - np.outer(u, axial) - np.outer(w, radial)
    return 1e3 * np.hypot(np.linalg.norm(off, axis=1), np.hypot(u, w) - radius_mm)


@pytest.mark.parametrize("radius_mm", [2.0, 20.0])
@pytest.mark.parametrize("segments", ["auto", "none"])
def test_compensated_arc_within_chord_tolerance_along_the_chords(tmp_path, grinder, radius_mm, segments):
    truth = ChainField(grinder, make_chain_truth(grinder, 11).elements)
    x0, z0, a = 80.0, 5.0, 30.0
    src = tmp_path / "arc.nc"
    # a half circle (G3, counter-clockwise), centre (x0, z0 + r), from (x0, z0) to (x0, z0 + 2r)
    src.write_text(f"G21 G90 G18\nG1 X{x0} Z{z0} A{a} F100\nG3 X{x0} Z{z0 + 2 * radius_mm} K{radius_mm}\nM30\n")
    tp = read_as_compensate(src, grinder, truth if segments == "auto" else None, arc_tolerance_um=ARC_TOL_UM,
                            work_offsets=MCS, max_segment_mm="auto" if segments == "auto" else None)
    res = solve("exact", truth, forward(grinder, tp.axes), grinder, target_axes=tp.axes)
    q = np.round(res.axes, 6)  # what the file holds
    s = np.linspace(0.0, 1.0, SAMPLES_PER_CHORD)
    dense = (q[:-1, None, :] + s[None, :, None] * (q[1:] - q[:-1])[:, None, :]).reshape(-1, 3)
    reached = forward(grinder, dense) + 1e-3 * truth.predict(dense)
    dist = _distance_to_arc_um(grinder, reached, (x0, z0 + radius_mm), radius_mm, a)
    assert dist.max() <= ARC_TOL_UM + ROUNDING_UM
    # the vertices themselves land on the arc (the chords' error is the linearisation only)
    at_vertices = _distance_to_arc_um(grinder, forward(grinder, q) + 1e-3 * truth.predict(q),
                                      (x0, z0 + radius_mm), radius_mm, a)
    assert at_vertices[1:].max() <= ROUNDING_UM
    # uncompensated, the same chords miss the arc by the machine's error (tens of μm): the test can fail
    raw = tp.axes[:-1, None, :] + s[None, :, None] * (tp.axes[1:] - tp.axes[:-1])[:, None, :]
    raw = raw.reshape(-1, 3)
    miss = _distance_to_arc_um(grinder, forward(grinder, raw) + 1e-3 * truth.predict(raw),
                               (x0, z0 + radius_mm), radius_mm, a)
    assert miss.max() > 10 * ARC_TOL_UM


FANUC_ARCS = """%
O1001 (ARCS WITHIN THE ROUNDING OF THEIR WORDS)
G21 G17 G40 G49 G80 G90
T1 M6
G54 G0 X0. Y0. S3000 M3
G43 Z5. H1
G1 Z-1. F300.
G2 X30. Y10. I15. J5. F600.
G3 X25. Y18.66 I-10. J0.
G2 X{x} Y10. I5. J-8.66
G0 Z5.
M5
M30
%
"""
"""A Fanuc program written from the operator's manual's circular interpolation (G17; I J the vector from the start
point to the centre; G2 clockwise, G3 counter-clockwise): the first arc exact, the second's end Y rounded to 0.01 mm
(its radii differ by 0.22 μm), the third's end X as ``{x}``: ``40.`` (centre (30, 10), radii 9.99978 and 10 mm:
0.22 μm) or ``40.004`` (4.22 μm: more than a rounding)."""


def test_fanuc_arcs_read_within_rounding_and_refused_beyond_with_the_rule_named(tmp_path, capsys, monkeypatch):
    """Fanuc's parameter 3410 is the machine's tolerance, but its manuals differ on the path within it (16/18-C:
    "moves in a straight line along one of the axes after reaching the end point"; 15i: a spiral, parameter 2410):
    arcs within the reader's rounding bound are compensated and pass the independent check (non-motion lines
    byte-identical, every programmed point reached by the TRUE machine within 1 μm); an arc beyond it is refused by
    line and word, naming parameter 3410 and that the manuals differ, in one line under 300 characters."""
    truth = ChainElementSet.random(load_machine("mill-xyz"), 101, 10.0, 11).save(tmp_path / "truth.json")
    tables = ["--work-offsets", str(STYLE_TABLES / "offsets.csv"), "--tool-table", str(STYLE_TABLES / "tools.csv")]

    monkeypatch.chdir(tmp_path)  # the refusal names the program as given: a short relative path

    def compensate(x, name):
        (tmp_path / name).write_text(FANUC_ARCS.format(x=x))
        prog = Path(name)
        rc = main(["compensate", name, "--machine", "mill-xyz", "--model", str(truth), "--truth", str(truth),
                   "--method", "exact", "--out", prog.stem, "--dialect", "fanuc", *tables])
        return prog, rc

    prog, rc = compensate("40.", "o1001.nc")
    assert rc == 0
    e = json.loads((tmp_path / "o1001" / "compensate_summary.json").read_text())["files"][0]
    assert e["dialect"] == "fanuc" and e["true"]["max_um"] < TOL_POINT_UM
    assert e["true_uncompensated"]["max_um"] > 10 * TOL_POINT_UM  # the check below has teeth
    verdict = independent_check(prog, tmp_path / "o1001" / prog.name, "fanuc", truth, *style_tables())
    assert verdict.startswith("ok: "), verdict
    capsys.readouterr()
    prog, rc = compensate("40.004", "o1002.nc")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 2 and not (tmp_path / "o1002" / prog.name).exists()
    assert "error: o1002.nc: line 10, column 4: 'X40.004': arc start and end radii differ by 4.220 μm" in err, err
    assert "(more than 2 μm; Fanuc: parameter 3410 sets the tolerance; manuals differ on the path within it)" in err
    assert len(err.split("error: ", 1)[1]) < 300 and " ... " not in err, err


_TruthField = TruthField   # the truth machine's own error as the model's field (benchmarks 'toolpath')


def test_auto_pieces_keep_a_pitch_error_within_the_tolerance_along_straight_moves(tmp_path, grinder):
    """20 mm moves under a lead screw's periodic pitch error (period 6-14 mm): its second differences at quarters
    of the move undersample it (the estimate alone left 1.56 μm, benchmarks 'toolpath'); with every piece checked
    at its midpoint the TRUE residual along the written segments, sampled densely, stays within the tolerance."""
    truth = make_chain_truth(grinder, 0, effects=("pitch", "worm", "interaction"))
    field = _TruthField(truth)
    src = tmp_path / "straight.nc"
    src.write_text("G21 G90 G94\n" + "".join(f"G0 X{x} Z5 A0\nG1 X{x + 20} F300\n" for x in range(0, 200, 20)) + "M30\n")
    for seg, bound in (("auto", ARC_TOL_UM + ROUNDING_UM), (None, None)):
        tp = read_as_compensate(src, grinder, field, work_offsets=MCS, max_segment_mm=seg)
        q = np.round(solve("exact", field, forward(grinder, tp.axes), grinder, target_axes=tp.axes).axes, 6)
        # the G0s are zero-length (each G1 starts where the last ended): the written vertices are one polyline, the
        # targets straight between the nominal ones (the first move's piece from the unwritten start left out)
        s = np.linspace(0.0, 1.0, SAMPLES_PER_CHORD)
        cmd = (q[:-1, None] + s[None, :, None] * (q[1:] - q[:-1])[:, None]).reshape(-1, 3)
        target = (tp.axes[:-1, None] + s[None, :, None] * (tp.axes[1:] - tp.axes[:-1])[:, None]).reshape(-1, 3)
        reached = truth.tool_point(cmd, **truth.default_conditions(len(cmd)))
        worst = 1e3 * float(np.linalg.norm(reached - forward(grinder, target), axis=1).max())
        if bound is None:  # the program's points only: the test can fail
            assert worst > 10 * ARC_TOL_UM, worst
        else:
            assert worst <= bound, worst
