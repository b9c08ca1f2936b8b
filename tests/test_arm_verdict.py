"""An arm calibration's verdict on its held-out poses (errormap.diagnosis.plausibility.arm_verdict): failed when the
kept model loses to the plain least-squares calibration or leaves a residual the stated tracker noise cannot
explain; ``calibrate`` then exits 1 and ``compensate`` refuses the model unless ``--allow failed-verdict`` (recorded
in the written program); any other ``--allow`` on an arm is refused, never ignored."""
from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main
from errormap.arm_poses import write_arm_poses
from errormap.arm_simulate import draw_truth, measure, random_joints
from errormap.diagnosis.plausibility import ARM_NOISE_EXCESS, BASELINE_Z, arm_verdict
from errormap.machine import load_machine
from errormap.io import read_table
from compensation.calibration_models import calibration_section

UR5_LO = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0])
UR5_HI = np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
NOISE_MM = 0.02
"""The simulated tracker's noise σ per coordinate (a GTS3800 at 1 m)."""
RATIO_TOL = 0.15
"""|RMS(r/σ) − 1| on 300 simulated pose residuals of pure noise: the RMS of 900 unit normals is within ±0.05 at
2 SE; 0.15 leaves room for a kept model's own error at the noise floor (held-out RMS ≤ 1.1× the floor measured)."""
UNDERSTATED = 4.0
"""A stated σ this many times below the true noise: the verdict's ratio is then ~4, far above ARM_NOISE_EXCESS."""


def run_cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def test_verdict_passes_a_model_at_the_noise_and_fails_one_that_loses_to_plain_lsq():
    rng = np.random.default_rng(0)
    noise = rng.normal(0, NOISE_MM, (300, 3))
    plain = noise + rng.normal(0, 0.05, (300, 3))             # the plain calibration leaves model error too
    v = arm_verdict("geometric+compliance", noise, plain, NOISE_MM)
    assert v["status"] == "passed" and not v["reasons"]
    assert abs(v["held_out"]["noise_ratio"] - 1.0) < RATIO_TOL
    assert v["held_out"]["kept_rms_mm"] < v["held_out"]["plain_lsq_rms_mm"]
    # the same residuals as the plain model's: z = 0, passes (the kept model may be the plain LSQ fit itself)
    assert arm_verdict("plain geometric LSQ", plain, plain)["status"] == "passed"
    # a kept model worse than the plain fit on the held-out poses: failed, named, with its paired z
    lost = arm_verdict("learned", plain, noise)
    assert lost["status"] == "failed" and lost["held_out"]["paired_z_plain_over_kept"] > BASELINE_Z
    assert "loses to the plain least-squares calibration" in lost["reasons"][0]
    assert "noise_ratio" not in lost["held_out"]        # no stated noise: not judged against it


def test_verdict_fails_residuals_the_stated_noise_cannot_explain():
    rng = np.random.default_rng(1)
    r = rng.normal(0, NOISE_MM, (300, 3))
    sigma = np.full(300, NOISE_MM / UNDERSTATED)           # per pose, as a sigma_mm column states it
    v = arm_verdict("geometric", r, r + 0.01, sigma)
    assert v["status"] == "failed" and v["held_out"]["noise_ratio"] > ARM_NOISE_EXCESS
    assert "stated tracker σ" in v["reasons"][0] and len(v["reasons"]) == 1


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """Two model.json of a UR5 (the plain LSQ fit of 60 simulated poses, fast), one with a passed verdict and
    one with the failed verdict an understated tracker noise gives, and a 5-point joint program."""
    from compensation.fields import ARM_FORMAT as MODEL_FORMAT
    from errormap.arm_calibration import fit_plain_lsq
    ur5 = load_machine("ur5")
    d = tmp_path_factory.mktemp("armmodel")
    t = draw_truth(ur5, 7)
    fit = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 60, [7, 0]), NOISE_MM, [7, 1])
    check = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 40, [7, 5]), NOISE_MM, [7, 6])
    geo = fit_plain_lsq(ur5, fit)
    r = check.xyz_mm - geo.predict(check.q)
    for name, sigma in (("passed", None), ("failed", NOISE_MM / UNDERSTATED / 10)):
        doc = {"format": MODEL_FORMAT, "machine": {"name": ur5.name, "joints": ur5.joint_columns},
               "kept_stage": "plain geometric LSQ", "geometric": geo.to_dict(), "plain_geometric": geo.to_dict(),
               "learned": None, "verdict": arm_verdict("plain geometric LSQ", r, r, sigma)}
        assert doc["verdict"]["status"] == name
        (d / f"{name}.json").write_text(json.dumps(doc))
    prog = d / "prog.csv"
    qp = random_joints(UR5_LO + 5, UR5_HI - 5, 5, [7, 9])
    prog.write_text(",".join(ur5.joint_columns) + "\n" + "\n".join(",".join(f"{v:.10g}" for v in row) for row in qp))
    return d, prog


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A UR5 calibrated (no learned stage, for speed) on 150 simulated poses, judged on 100 held-out poses, twice:
    with the true tracker σ stated and with one 4× too small."""
    ur5 = load_machine("ur5")
    d = tmp_path_factory.mktemp("arm")
    t = draw_truth(ur5, 7)
    fit = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 150, [7, 0]), NOISE_MM, [7, 1])
    check = measure(ur5, t, random_joints(UR5_LO, UR5_HI, 100, [7, 5]), NOISE_MM, [7, 6])
    write_arm_poses(d / "fit.csv", ur5, fit)
    write_arm_poses(d / "check.csv", ur5, check)
    runs = {}
    for name, noise_um in (("true", NOISE_MM * 1e3), ("understated", NOISE_MM * 1e3 / UNDERSTATED)):
        runs[name] = run_cli(["calibrate", d / "fit.csv", "--check", d / "check.csv", "--machine", "ur5", "--out",
                              d / name, "--no-learned", "--folds", "3", "--noise-um", noise_um])
    return d, runs


@pytest.mark.slow
def test_calibrate_writes_the_verdict_and_exits_1_when_it_fails(calibrated):
    d, runs = calibrated
    rc, out, err = runs["true"]
    assert rc == 0, err
    doc = calibration_section(d / "true" / "model.json", "arm")[0]
    v = doc["verdict"]
    assert v["status"] == "passed" and "calibrate: verdict: passed" in out
    kept = next(s for s in doc["stages"] if s["name"] == doc["kept_stage"])
    # the verdict judges the kept stage's own held-out residual: its RMS is the stage table's (same poses)
    assert v["held_out"]["kept_rms_mm"] == pytest.approx(kept["rms_mm"], rel=1e-9)
    assert abs(v["held_out"]["noise_ratio"] - 1.0) < RATIO_TOL
    rc, out, err = runs["understated"]
    assert rc == 1, err
    doc = calibration_section(d / "understated" / "model.json", "arm")[0]
    assert doc["verdict"]["status"] == "failed" and "calibrate: verdict: FAILED" in out
    assert doc["verdict"]["held_out"]["noise_ratio"] > ARM_NOISE_EXCESS
    assert "Verdict on the held-out poses: <b>FAILED</b>" in (d / "understated" / "report.html").read_text()


def test_compensate_refuses_a_failed_arm_model_unless_allowed(models):
    d, prog = models
    model = d / "failed.json"
    rc, out, err = run_cli(["compensate", prog, "--machine", "ur5", "--model", model, "--out", d / "c1"])
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS + 40, err
    assert "verdict" in lines[0] and "--allow failed-verdict" in lines[0] and not (d / "c1" / "prog.csv").exists()
    rc, out, err = run_cli(["compensate", prog, "--machine", "ur5", "--model", model, "--out", d / "c2",
                            "--allow", "failed-verdict"])
    assert rc == 0, err
    head = read_table(d / "c2" / "prog.csv").comments[0]   # the first provenance line (its sidecar)
    assert "MODEL VERDICT FAILED" in head and "--allow failed-verdict" in head and "stated tracker" in head
    # a passed model needs no --allow
    rc, out, err = run_cli(["compensate", prog, "--machine", "ur5", "--model", d / "passed.json",
                            "--out", d / "c3"])
    assert rc == 0, err


@pytest.mark.parametrize("allow", ["ball", "convergence,failed-verdict", None])
def test_compensate_on_an_arm_refuses_guard_allows(models, allow):
    """The machine-tool guards have no counterpart on an arm: naming one (or a bare --allow) is refused."""
    d, prog = models
    argv = ["compensate", prog, "--machine", "ur5", "--model", d / "passed.json", "--out", d / "g",
            "--allow"] + ([] if allow is None else [allow])
    rc, out, err = run_cli(argv)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "a serial arm takes only --allow failed-verdict" in lines[0], err


def test_predict_on_an_arm_refuses_a_failed_model_unless_allowed(models):
    d, prog = models
    argv = ["predict", "--machine", "ur5", "--model", d / "failed.json", prog, "--out", d / "p.csv"]
    rc, out, err = run_cli(argv)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "--allow failed-verdict" in lines[0] and not (d / "p.csv").exists(), err
    rc, out, err = run_cli(argv + ["--allow", "failed-verdict"])
    assert rc == 0, err
    assert any(ln.startswith("allowed: failed-verdict") for ln in read_table(d / "p.csv").comments)  # its sidecar
    rc, out, err = run_cli(argv + ["--allow", "extrapolate"])
    assert rc == 2 and "only --allow failed-verdict applies" in err


@pytest.mark.parametrize("opts, named", [(["--workers", "2"], "--workers"), (["--chunk-points", "7"], "--chunk-points"),
                                         (["--max-segment-mm", "5"], "--max-segment-mm")])
def test_compensate_on_an_arm_refuses_scale_out_options(models, opts, named):
    """An arm's program is solved point by point in one process: the scale-out options are refused, never ignored."""
    d, prog = models
    rc, out, err = run_cli(["compensate", prog, "--machine", "ur5", "--model", d / "passed.json", "--out", d / "s",
                            *opts])
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and named in lines[0] and "point by point" in lines[0], err
    assert not (d / "s" / "prog.csv").exists()


def test_compensate_on_an_arm_never_clobbers_without_force(models):
    d, prog = models
    argv = ["compensate", prog, "--machine", "ur5", "--model", d / "passed.json", "--out", d / "f"]
    assert run_cli(argv)[0] == 0
    first = (d / "f" / "prog.csv").read_bytes()
    (d / "f" / "prog.csv").write_text("mine\n")
    rc, out, err = run_cli(argv)
    assert rc == 2 and "exists" in err and "--force" in err, err
    assert (d / "f" / "prog.csv").read_text() == "mine\n"      # untouched
    assert run_cli([*argv, "--force"])[0] == 0
    assert (d / "f" / "prog.csv").read_bytes() == first


def test_register_refuses_a_failed_calibration_unless_allowed_and_records_it(models):
    """register re-registers a calibration like compensate/predict use it: a failed verdict is refused in one line
    naming the file and --allow failed-verdict; with it the output records the override and keeps the failed
    verdict (a later predict refuses it again unless allowed)."""
    d, _ = models
    ur5 = load_machine("ur5")
    t = draw_truth(ur5, 7)
    write_arm_poses(d / "session.csv", ur5, measure(ur5, t, random_joints(UR5_LO, UR5_HI, 12, [7, 11]), NOISE_MM,
                                                    [7, 12]))
    rc, out, err = run_cli(["register", d / "session.csv", "--machine", "ur5", "--model", d / "failed.json",
                            "--out", d / "r1"])
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS + 40, err
    assert str(d / "failed.json") in lines[0] and "--allow failed-verdict" in lines[0]
    assert not (d / "r1").exists()
    rc, out, err = run_cli(["register", d / "session.csv", "--machine", "ur5", "--model", d / "failed.json",
                            "--out", d / "r2", "--allow", "failed-verdict"])
    assert rc == 0, err
    doc = calibration_section(d / "r2" / "model.json", "arm")[0]
    assert doc["registration"]["allowed"].startswith("failed-verdict (") and "stated tracker" in doc["registration"]["allowed"]
    assert doc["verdict"]["status"] == "failed" and "register: failed-verdict" in out
    rc, out, err = run_cli(["register", d / "session.csv", "--machine", "ur5", "--model", d / "passed.json",
                            "--out", d / "r3"])
    assert rc == 0, err
    assert calibration_section(d / "r3" / "model.json", "arm")[0]["registration"]["allowed"] is None
