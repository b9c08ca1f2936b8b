"""``volcomp simulate --machine hexapod|tripod``: the benchmark's simulated parallel machine written as the files
a user measures (poses.csv, checks.csv), so the user's path (``calibrate --check``) runs on them; the truth goes
to truth.json for the judge only."""
from __future__ import annotations

import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.io import read_table
from provenance import text_and_provenance
from compensation.calibration_models import calibration_section

NOISE_UM = 5.0
FLOOR_RATIO = 1.25
"""The calibrated machine's held-out RMS over the noise floor √3·σ of the checks: at the floor up to the RMS
scatter of 40 check poses and the fitted parameters' own noise (measured 0.97 on seed 0)."""
GAIN = 100.0
"""The uncalibrated (nominal) machine misses by mm (leg scales of a few %, zero lengths of tens of mm); the
calibration must remove at least this factor of it."""


@pytest.mark.slow  # a hexapod calibration with three lambda rules: over 5 CPU s
def test_simulated_hexapod_runs_the_users_calibration_to_its_floor(tmp_path):
    assert main(["simulate", "--machine", "hexapod", "--seed", "0", "--poses", "60", "--checks", "40",
                 "--out", str(tmp_path / "sim")]) == 0
    truth = json.loads((tmp_path / "sim" / "truth.json").read_text())
    assert truth["kind"] == "hexapod" and len(truth["truth"]["leg_scale"]) == 6
    assert main(["calibrate", str(tmp_path / "sim" / "poses.csv"), "--machine", "hexapod", "--check",
                 str(tmp_path / "sim" / "checks.csv"), "--out", str(tmp_path / "cal")]) == 0
    cal = calibration_section(tmp_path / "cal" / "model.json", "parallel")[0]
    assert cal["residual_kind"] and cal["n_check_poses"] == 40 and cal["success"]
    before, after = cal["rms_before_um"], cal["rms_after_um"]     # on the 40 check poses
    floor = np.sqrt(3.0) * NOISE_UM
    assert after <= FLOOR_RATIO * floor and before >= GAIN * after


@pytest.mark.parametrize("machine, columns", [("hexapod", ("q1", "q6")), ("tripod", ("q1", "q3"))])
def test_check_noise_redraw_and_refusals(machine, columns, tmp_path):
    def sim(name, *more):
        assert main(["simulate", "--machine", machine, "--seed", "2", "--poses", "10", "--checks", "15", *more,
                     "--out", str(tmp_path / name)]) == 0
        return read_table(tmp_path / name / "checks.csv")
    a, b, c = sim("a"), sim("b", "--seed-check-noise", "9"), sim("c", "--seed-check-noise", "9")
    for k in columns:                                    # the commanded poses: the same
        np.testing.assert_array_equal(a.float(k), b.float(k))
    d = np.stack([a.float(k) - b.float(k) for k in ("x_mm", "y_mm", "z_mm")], axis=1)
    assert np.all(np.abs(d) > 0)                         # only the noise redrawn
    np.testing.assert_array_equal(b.float("x_mm"), c.float("x_mm"))
    assert "check_noise_seed: 9" in text_and_provenance(tmp_path / "b" / "checks.csv")
    assert json.loads((tmp_path / "b" / "truth.json").read_text())["check_noise_seed"] == 9
    for bad in (["--family", "independent"], ["--effect", "sag"]):
        assert main(["simulate", "--machine", machine, *bad, "--out", str(tmp_path / "bad")]) == 2
        assert not (tmp_path / "bad").exists()


ROUND_TRIP_UM = 1e-3
"""predict commands each pose with the nominal inverse kinematics: at the check poses' nominal tips that is the
checks' own drive commands again (inverse after forward kinematics, Newton to 1e-9 mm), so the calibrated
landing equals calibrate's model to far below this."""


@pytest.mark.slow  # a hexapod calibration: over 5 CPU s
def test_predict_on_a_hexapod_lands_where_the_calibration_says(tmp_path):
    """``predict --machine hexapod --model model.json``: at the check poses' commanded tips the predicted
    landing, in the instrument frame of the calibration, leaves against the measured checks exactly calibrate's
    held-out RMS."""
    from scipy.spatial.transform import Rotation
    from errormap.io import write_csv
    from errormap.machine import load_machine
    from errormap.pkm.poses import read_poses
    from errormap.pkm.hexapod import forward_kinematics, rotation_to_angles
    m = load_machine("hexapod")
    assert main(["simulate", "--machine", "hexapod", "--seed", "0", "--poses", "60", "--checks", "40",
                 "--out", str(tmp_path / "sim")]) == 0
    assert main(["calibrate", str(tmp_path / "sim" / "poses.csv"), "--machine", "hexapod", "--no-loop", "--check",
                 str(tmp_path / "sim" / "checks.csv"), "--out", str(tmp_path / "cal")]) == 0
    cal = calibration_section(tmp_path / "cal" / "model.json", "parallel")[0]
    chk = read_poses(tmp_path / "sim" / "checks.csv", m)
    nom = forward_kinematics(m, m.drive_to_legs(chk.q))            # the commanded poses
    a = rotation_to_angles(nom.platform2base)
    write_csv(tmp_path / "pts.csv", {"x_mm": nom.x[:, 0], "y_mm": nom.x[:, 1], "z_mm": nom.x[:, 2],
                                     "rx_deg": a[:, 0], "ry_deg": a[:, 1], "rz_deg": a[:, 2]})
    assert main(["predict", str(tmp_path / "pts.csv"), "--machine", "hexapod", "--model", str(tmp_path / "cal"),
                 "--out", str(tmp_path / "pred.csv")]) == 0
    t = read_table(tmp_path / "pred.csv")
    landed = nom.x + np.stack([t.float(c) for c in ("dx_mm", "dy_mm", "dz_mm")], axis=1)
    R = Rotation.from_quat(cal["frame"]["rotation_qx_qy_qz_qw"]).as_matrix()
    inst = landed @ R.T + np.asarray(cal["frame"]["translation_mm"])
    rms_um = 1e3 * np.sqrt(np.mean(np.sum((chk.tip_mm - inst) ** 2, axis=1)))
    assert abs(rms_um - cal["rms_after_um"]) <= ROUND_TRIP_UM
    assert main(["predict", str(tmp_path / "pts.csv"), "--machine", "hexapod", "--model", str(tmp_path / "cal"),
                 "--band", "95", "--out", str(tmp_path / "p2.csv")]) == 2
