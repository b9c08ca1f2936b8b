"""CSV tool paths and the plain G-code writer (compensation.pathio)."""
import json

import numpy as np
import pytest

from compensation.nc_state import MACHINE, read_work_offsets
from compensation.pathio import align_turns, write_axes_gcode
from compensation.toolpath import flute_path
from errormap.io import InputError, sidecar_path
from errormap.chain_kernel import forward
from path_files import read_as_compensate, write_compensated, write_targets_csv

MCS = read_work_offsets(MACHINE)
"""The G-code programs here are written in machine coordinates (the grinder's axes): read with
--work-offsets machine (a program is never read at an assumed zero)."""

TOL_MM = 1e-6


def test_axes_csv_targets_are_forward(tmp_path, grinder):
    p = tmp_path / "axes.csv"
    p.write_text("# job: test\nx_mm,z_mm,a_deg,feed\n10,1,0,100\n20,2,370,100\n")
    tp = read_as_compensate(p, grinder, work_offsets=MCS)   # read and written as compensate does
    assert tp.kind == "csv-axes" and tp.lines.tolist() == [3, 4]
    assert np.array_equal(tp.axes, [[10, 1, 0], [20, 2, 370]])
    out = write_compensated(tp, tmp_path / "out" / "axes.csv", grinder, tp.axes + 0.001,
                            comments=["method: x"])
    text = out.read_text().splitlines()
    # a plain CSV (header first); the input's '#' provenance and the added lines go to the sidecar
    assert text[0] == "x_mm,z_mm,a_deg,feed" and text[1].endswith(",100")
    side = json.loads(sidecar_path(out).read_text())
    assert side["lines"] == ["job: test", "method: x"] and side["columns"] == text[0].split(",")
    back = read_as_compensate(out, grinder, work_offsets=MCS)
    assert np.abs(back.axes - (tp.axes + 0.001)).max() < TOL_MM
    assert back.source.meta() == {"job": "test", "method": "x"}


def test_targets_csv_round_trip_and_unwrap(tmp_path, grinder):
    f = flute_path(turns=2, points_per_turn=30)
    p = write_targets_csv(tmp_path / "flute.csv", f.targets_mm)
    tp = read_as_compensate(p, grinder, work_offsets=MCS)
    assert tp.kind == "csv-targets"
    assert np.abs(tp.axes[:, 2] - f.theta_deg).max() < 1e-6  # A unwrapped along the path
    tpw = read_as_compensate(p, grinder, work_offsets=MCS)
    out = write_compensated(tpw, tmp_path / "o" / "flute.csv", grinder, tpw.axes, tpw.targets_mm + 1e-4)
    back = read_as_compensate(out, grinder, work_offsets=MCS).targets_mm
    assert np.abs(back - (f.targets_mm + 1e-4)).max() < TOL_MM


@pytest.mark.parametrize("text, match", [
    ("x_mm,z_mm\n1,2\n", r"missing required column\(s\) \['a_deg'\]"),
    ("x_mm,z_mm,a_deg,px_mm,py_mm,pz_mm\n1,2,3,4,5,6\n", "both"),
    ("x_mm,z_mm,a_deg\n1,2,3\n1,abc,3\n", r"row 3, column 'z_mm'"),
    ("x_mm,z_mm,a_deg\n1,2\n", "row 2"),
    ("x_mm,z_mm,a_deg\n", "no data rows"),
])
def test_bad_csv_names_row_and_column(tmp_path, grinder, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as exc:
        read_as_compensate(p, grinder, work_offsets=MCS)
    assert "bad.csv" in str(exc.value)


def test_plain_gcode_writer_reads_back(tmp_path, grinder):
    ax = flute_path(turns=1, points_per_turn=20).axes(grinder)
    tp = read_as_compensate(write_axes_gcode(tmp_path / "f.nc", ax, header=["flute"]), grinder, work_offsets=MCS)
    assert np.abs(tp.axes - ax).max() < TOL_MM


def test_align_turns():
    a = align_turns([719.0, -1.0, 365.0], [0.0, 360.0, 5.0])
    assert np.allclose(a, [-1.0, 359.0, 5.0])
