"""`volcomp calibrate` and `volcomp interpolate` end to end on simulated data."""
import json

import numpy as np

from compensation.app.cli import main
from errormap.io import read_table
from errormap.machine import load_machine
from errormap.pkm.simulate import simulate_hexapod_poses
from compensation.calibration_models import calibration_section

NOISE_UM = 5.0
HELDOUT_RMS_FACTOR = 3.0  # held-out measured residual includes the check poses' own 3-D noise (~1.7x)


def test_calibrate_then_interpolate(tmp_path, capsys):
    m = load_machine(expect_kind="hexapod")
    sim = simulate_hexapod_poses(m, 90, NOISE_UM, seed=21)
    poses = tmp_path / "poses.csv"
    sim.write_csv(poses)
    out = tmp_path / "cal"
    assert main(["calibrate", str(poses), "--out", str(out), "--holdout", "0.25", "--noise-um", str(NOISE_UM),
                 "--scales"]) == 0
    doc = calibration_section(out / "model.json", "parallel")[0]
    for key in ("parameters", "condition_number", "lambda", "rms_before_um", "rms_after_um", "max_before_um",
                "max_after_um"):
        assert key in doc
    assert doc["rms_before_um"] > 20 * NOISE_UM
    assert doc["rms_after_um"] <= HELDOUT_RMS_FACTOR * NOISE_UM
    assert all("std_error" in v for v in doc["parameters"].values())
    assert (out / "report.html").is_file() and (out / "singular_values.png").is_file()
    prog = tmp_path / "prog.csv"
    assert main(["interpolate", "hyperboloid", "--calibration", str(out), "--out", str(prog),
                 "--feed-mm-min", "6000", "--period-ms", "10"]) == 0
    t = read_table(prog)
    assert len(t) > 100 and "dl6_mm" in t and "q1" in t
    steps = np.linalg.norm(np.diff(np.stack([t.float(c) for c in ("px_mm", "py_mm", "pz_mm")], 1), axis=0), axis=1)
    assert steps.max() <= 1.0 + 1e-4  # f = 6000 mm/min * 10 ms (CSV keeps 9 digits)
    assert "wrote" in capsys.readouterr().out


def test_bad_input_exit_code(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("q1,q2\n1,2\n")
    assert main(["calibrate", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "missing leg columns" in capsys.readouterr().err
    assert not (tmp_path / "o" / "model.json").exists()


def test_calibrate_unknown_noise_compares_lambda_rules(tmp_path):
    m = load_machine(expect_kind="hexapod")
    sim = simulate_hexapod_poses(m, 80, NOISE_UM, seed=22)
    poses = tmp_path / "poses.csv"
    sim.write_csv(poses)
    out = tmp_path / "cal"
    assert main(["calibrate", str(poses), "--out", str(out), "--scales"]) == 0
    doc = calibration_section(out / "model.json", "parallel")[0]
    assert doc["delta_estimated"] and doc["n_gauge"] == 6
    assert doc["condition_number_raw"] is None or doc["condition_number_raw"] > doc["condition_number"]
    rules = {r["rule"]: r for r in doc["lambda_comparison"]["rules"]}
    assert set(rules) == {"morozov", "gcv", "lcurve"}
    for r in rules.values():
        assert r["success"] and r["lambda"] > 0
        assert r["heldout_rms_um"] <= HELDOUT_RMS_FACTOR * NOISE_UM
    assert doc["lambda_rule"] == "gcv" and rules["gcv"]["lambda"] == doc["lambda"]   # GCV is the default rule
    assert "Choice of lambda" in (out / "report.html").read_text()
