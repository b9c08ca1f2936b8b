"""``volcomp simulate --machine ur5``: a simulated arm's measurement files, and the user's path on them
(simulate → calibrate → compensate) judged against the hidden truth."""
from __future__ import annotations

import json

import numpy as np
import pytest

from compensation.app.cli import main
from compensation.app.workflows.simulate_serial import (PROGRAM_MAX_COND, load_serial_truth, simulate_serial,
                                                        well_conditioned_joints)
from errormap.arm_poses import read_arm_poses
from errormap.io import read_table
from errormap.machine import load_machine
from compensation.calibration_models import calibration_section

NOISE_MM = 0.02                               # the simulated tracker's σ per component (the default 20 μm)
NOISE_FLOOR_MM = np.sqrt(3) * NOISE_MM        # RMS 3-D error of a perfect model against noisy measurements
FLOOR_FACTOR = 1.25                           # issue 27: held-out error / compensation within 1.25× the noise
NOISE_SD_REL_TOL = 0.15                       # sample σ of 3×200 normal draws: ±3 SE ≈ ±0.15 relative
COND_SLACK = 1e-9                             # the condition filter is exact up to round-off
ORIENTATION_MEDIAN_RAD = 1e-3  # the TRUE tool orientation after compensation vs at the programmed joints: the
# calibrated chain's orientation is kept, so only its error's change over the joint correction remains (median
# 0.01–0.4 mrad on seeds 3 and 5; link orientation slots 0.3 mrad SD, seen through a 31 mm tool offset only)
ORIENTATION_MAX_RAD = 0.05     # the worst point: 26 mrad on seed 5, a 28° joint move near the condition-30 edge;
# a wrist turned by the fit's arbitrary tool roll (the former nominal-orientation target: 132° on seed 3) is 2.3 rad


@pytest.fixture(scope="module")
def ur5():
    return load_machine("ur5")


def test_files_are_the_measured_pose_schema_and_the_truth_is_apart(tmp_path, ur5):
    info = simulate_serial(ur5, 4, tmp_path, effects=["sag"], noise_um=20.0, poses=200, checks=50)
    fit = read_arm_poses(tmp_path / "poses.csv", ur5)
    chk = read_arm_poses(tmp_path / "checks.csv", ur5)
    assert fit.q.shape == (200, 6) and chk.q.shape == (50, 6)
    assert np.all(fit.q >= ur5.joint_lo) and np.all(fit.q <= ur5.joint_hi)
    truth = load_serial_truth(tmp_path / "truth.json", ur5)
    # the measured points are the truth's tool points plus the stated noise (judge's side)
    r = fit.xyz_mm - truth.tool_point(ur5, fit.q)
    assert abs(r.std() / NOISE_MM - 1) < NOISE_SD_REL_TOL
    assert np.all(truth.compliance_rad_per_mm > 0) and truth.backlash_rad is None
    assert info["effects"] == ["sag"]
    # nothing of the truth is in the measurement files
    assert "errors" not in (tmp_path / "poses.csv").read_text(encoding="utf-8")


def test_same_seed_same_files_other_seed_other_truth(tmp_path, ur5):
    simulate_serial(ur5, 7, tmp_path / "a", poses=20, checks=5)
    simulate_serial(ur5, 7, tmp_path / "b", poses=20, checks=5)
    simulate_serial(ur5, 8, tmp_path / "c", poses=20, checks=5)
    for f in ("poses.csv", "checks.csv", "program.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    ta, tb, tc = (json.loads((tmp_path / d / "truth.json").read_text(encoding="utf-8")) for d in "abc")
    assert ta["errors"] == tb["errors"] and ta["errors"] != tc["errors"]


def test_program_poses_are_well_conditioned(ur5):
    from compensation.arm_compensation import LEVER_MM
    q = well_conditioned_joints(ur5, ur5.joint_lo + 5, ur5.joint_hi - 5, 100, 0)
    J = ur5.joint_jacobian(q, np.zeros(ur5.n_params), orientation=True)
    J = np.concatenate([J[:, :3], LEVER_MM * J[:, 3:]], 1)
    sv = np.linalg.svd(J, compute_uv=False)
    assert q.shape == (100, 6) and np.all(sv[:, 0] / sv[:, -1] <= PROGRAM_MAX_COND * (1 + COND_SLACK))


def test_cli_refusals(tmp_path, capsys):
    assert main(["simulate", "--machine", "ur5", "--effect", "worm", "--out", str(tmp_path / "x")]) == 2
    assert "unknown effect 'worm' for a serial arm" in capsys.readouterr().err
    assert main(["simulate", "--machine", "mill-xyz", "--poses", "10", "--out", str(tmp_path / "y")]) == 2
    assert "--poses" in capsys.readouterr().err
    assert main(["simulate", "--machine", "ur5", "--poses", "2", "--out", str(tmp_path / "z")]) == 2
    capsys.readouterr()
    # a command meant for machine tools names what an arm takes instead
    assert main(["featurepoints", "--machine", "ur5", "--elements", str(tmp_path / "e.json"), "--out",
                 str(tmp_path / "fp.csv")]) == 2
    err = capsys.readouterr().err
    assert "does not run on a serial arm" in err and "other path:" in err and "inside calibrate" in err
    assert main(["predict", "--machine", "ur5", "--model", str(tmp_path / "cal.json"), str(tmp_path / "p.csv"),
                 "--out", str(tmp_path / "o.csv"), "--band", "95"]) == 2   # an arm's band: its stage's (no file here)
    assert "cal.json: no such file or folder" in capsys.readouterr().err


@pytest.mark.slow
def test_users_path_simulate_calibrate_compensate_lands_within_the_noise(tmp_path, ur5):
    """simulate (sag) → calibrate --check → compensate the simulated joint program; TRUE landing error of the
    compensated commands against the hidden truth, and the held-out MEASURED error, both ≤ 1.25× the noise."""
    d = tmp_path / "sim"
    assert main(["simulate", "--machine", "ur5", "--seed", "5", "--effect", "sag", "--poses", "300",
                 "--out", str(d)]) == 0
    assert main(["calibrate", str(d / "poses.csv"), "--machine", "ur5", "--check", str(d / "checks.csv"),
                 "--out", str(d / "cal"), "--no-learned"]) == 0
    doc = calibration_section(d / "cal" / "model.json", "arm")[0]
    kept = {s["name"]: s for s in doc["stages"]}[doc["kept_stage"]]
    assert kept["rms_mm"] <= FLOOR_FACTOR * NOISE_FLOOR_MM
    assert main(["compensate", str(d / "program.csv"), "--machine", "ur5", "--model",
                 str(d / "cal" / "model.json"), "--out", str(d / "comp")]) == 0
    truth = load_serial_truth(d / "truth.json", ur5)
    prog, comp = read_table(d / "program.csv"), read_table(d / "comp" / "program.csv")
    q0 = np.stack([prog.float(c) for c in ur5.joint_columns], 1)
    q1 = np.stack([comp.float(c) for c in ur5.joint_columns], 1)
    target = ur5.tool_point(q0)   # the joint program's targets: nominal tool points in the robot's base frame
    after = np.linalg.norm(truth.base_frame_point(ur5, q1) - target, axis=1)
    before = np.linalg.norm(truth.base_frame_point(ur5, q0) - target, axis=1)
    assert np.sqrt(np.mean(after ** 2)) <= FLOOR_FACTOR * NOISE_FLOOR_MM < np.sqrt(np.mean(before ** 2))
    def true_R(q):
        return ur5.frames(q + truth.joint_sag_deg(ur5, q), truth.errors)[:, -1, :3, :3]
    D = true_R(q1) @ np.swapaxes(true_R(q0), 1, 2)
    turned = np.arccos(np.clip((np.trace(D, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert np.median(turned) <= ORIENTATION_MEDIAN_RAD and turned.max() <= ORIENTATION_MAX_RAD
    # predict: the calibrated tool-point error at the program's joints against the truth's, both in the robot's base frame
    assert main(["predict", "--machine", "ur5", "--model", str(d / "cal" / "model.json"), str(d / "program.csv"),
                 "--out", str(d / "pred.csv")]) == 0
    pred = read_table(d / "pred.csv")
    dp = np.stack([pred.float(c) for c in ("dx_mm", "dy_mm", "dz_mm")], 1)
    miss = np.linalg.norm(dp - (truth.base_frame_point(ur5, q0) - target), axis=1)
    assert np.sqrt(np.mean(miss ** 2)) <= FLOOR_FACTOR * NOISE_FLOOR_MM
