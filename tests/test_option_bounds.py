"""Options that would silently change the result are bounded, refused with the option, the value
and the allowed range (``compensate --arc-tolerance-um 1e9`` wrote a G2 arc as one G1 chord)."""
from __future__ import annotations

import pytest

from compensation.nc_state import MACHINE, read_work_offsets
from compensation.pathio import ARC_TOLERANCE_RANGE_UM, SEGMENT_RANGE_MM
from path_files import read_as_compensate

from test_output_safety import one_line, run_cli

MCS = read_work_offsets(MACHINE)
"""The G-code programs here are written in machine coordinates (the grinder's axes): read with
--work-offsets machine (a program is never read at an assumed zero)."""

ARC = "G21 G90 G18\nG1 X100. Z0.3 A0 F100\nG2 X110. Z10.3 A0 I0 K10.\n"


@pytest.fixture
def arc_job(tmp_path, grinder):
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(grinder, 3).elements.save(tmp_path / "elements.json")
    src = tmp_path / "arc.nc"
    src.write_text(ARC)
    return src, el


@pytest.mark.parametrize("value", ["1e9", "5.01", "0.0009", "0"])
def test_arc_tolerance_out_of_range_is_refused(tmp_path, arc_job, value):
    src, el = arc_job
    rc, _, err = run_cli(["compensate", "--work-offsets", "machine",
                          src, "--model", el, "--method", "traditional", "--out", tmp_path / "o",
                          "--arc-tolerance-um", value])
    lo, hi = ARC_TOLERANCE_RANGE_UM
    one_line(rc, err, "--arc-tolerance-um", f"[{lo:g}, {hi:g}] um", f"got {float(value)}")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("value", ["1e-6", "0.009", "100.5", "1e9", "-1", "nan", "fast"])
def test_max_segment_out_of_range_is_refused(tmp_path, arc_job, value):
    src, el = arc_job
    rc, _, err = run_cli(["compensate", "--work-offsets", "machine",
                          src, "--model", el, "--method", "traditional", "--out", tmp_path / "o",
                          "--max-segment-mm", value])
    lo, hi = SEGMENT_RANGE_MM
    one_line(rc, err, "--max-segment-mm", f"[{lo:g}, {hi:g}] mm", repr(value), "'auto', 'none'")


def test_the_largest_arc_tolerance_keeps_the_arc_an_arc(tmp_path, arc_job, grinder):
    """At the upper bound a quarter arc of 10 mm radius is still cut into chords whose sagitta
    stays within the tolerance."""
    import numpy as np
    src, el = arc_job
    hi = ARC_TOLERANCE_RANGE_UM[1]
    rc, _, err = run_cli(["compensate", "--work-offsets", "machine",
                          src, "--model", el, "--method", "traditional", "--out", tmp_path / "o",
                          "--arc-tolerance-um", str(hi), "--max-segment-mm", "none"])
    assert rc == 0, err
    tp = read_as_compensate(src, grinder, arc_tolerance_um=hi, work_offsets=MCS, max_segment_mm=None)
    chords = len(tp) - 1   # the arc's vertices after the first move's end
    r_mm, sweep = 10.0, np.pi / 2
    sagitta_um = 1e3 * r_mm * (1 - np.cos(sweep / chords / 2))
    assert chords > 1 and sagitta_um <= hi
