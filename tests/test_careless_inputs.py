"""Inputs a careless or hostile new user gives, found by a fresh-clone probe: each is refused in one line naming the
file, row or option (exit 2) and leaves every input as it was — an output onto an input, an element set of another
machine, a path the machine cannot reach, a tracking store MLflow cannot open, feature points without validation."""
from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from compensation.app.cli import MAX_ERROR_CHARS, main


def run(argv):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(argv)
    lines = [ln for ln in err.getvalue().splitlines() if ": error: " in ln]
    return rc, lines


def one_line(rc, lines, *words):
    assert rc == 2 and len(lines) == 1 and len(lines[0]) <= MAX_ERROR_CHARS, (rc, lines)
    assert all(w in lines[0] for w in words), (words, lines[0])


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("careless")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["simulate", "--seed", "3", "--checks", "30", "--out", str(d / "g")]) == 0
    return d


def test_an_output_onto_an_input_is_refused_and_the_input_kept(sim, tmp_path):
    """predict --out naming the points file itself (by another spelling too) or the model: exit 2 naming both; the
    input's bytes are unchanged (it used to be replaced by the predictions, the model by a CSV)."""
    pts = tmp_path / "pts.csv"
    pts.write_text("x_mm,z_mm,a_deg\n10,20,30\n50,30,200\n")
    model = tmp_path / "E.json"
    model.write_bytes((sim / "g" / "truth_elements.json").read_bytes())
    before = {p: p.read_bytes() for p in (pts, model)}
    for out, flag in ((pts, "POINTS"), (tmp_path / "." / ".." / tmp_path.name / "pts.csv", "POINTS"), (model, "--model")):
        rc, lines = run(["predict", str(pts), "--model", str(model), "--out", str(out)])
        one_line(rc, lines, f"--out {out}: is the input {flag}", "choose another output file")
    assert {p: p.read_bytes() for p in (pts, model)} == before
    rc, _ = run(["predict", str(pts), "--model", str(model), "--out", str(tmp_path / "o.csv")])
    assert rc == 0 and (tmp_path / "o.csv").is_file()


def test_an_element_set_of_another_machine_names_its_axes_and_machine(sim, tmp_path):
    """a mill's element set given for the grinder: was "E.json: 'a_deg'" (a KeyError's text)."""
    (tmp_path / "p.csv").write_text("x_mm,z_mm,a_deg\n10,20,30\n")
    doc = json.loads((sim / "g" / "truth_elements.json").read_text())   # a chain's layout: its own axes' stations
    doc["stations"] = {"x_mm": doc["stations"]["x_mm"], "y_mm": doc["stations"]["z_mm"], "z_mm": doc["stations"]["z_mm"]}
    doc["machine"] = "mill-xyz"
    el = tmp_path / "E_mill.json"
    el.write_text(json.dumps(doc))
    rc, lines = run(["predict", str(tmp_path / "p.csv"), "--model", str(el), "--out", str(tmp_path / "o.csv")])
    one_line(rc, lines, str(el), "no 'a_deg'", "mill-xyz", "--machine")


def test_report_refuses_a_path_outside_the_strokes(sim, tmp_path):
    """report --path with targets the grinder cannot reach (another frame): was exit 0 with a page of 54 mm residuals
    (every solve failing its guards); now the first data row outside a stroke, and nothing written."""
    p = tmp_path / "t.csv"
    p.write_text("px_mm,py_mm,pz_mm\n-250,10,200\n-252,11,201\n")
    rc, lines = run(["report", "--path", str(p), "--model", str(sim / "g" / "truth_elements.json"),
                     "--methods", "exact", "--out", str(tmp_path / "r")])
    one_line(rc, lines, f"{p}: data row 1 (of 2; 2 outside)", "x_mm", "stroke [0, 200]")
    assert not (tmp_path / "r").exists()


@pytest.mark.slow   # MLflow's import and store checks: about 20 CPU s
def test_a_tracking_store_mlflow_cannot_open_is_refused_before_training(sim, tmp_path):
    """--tracking-uri of the retired file store (a plain folder, or file://): was a MlflowException traceback after
    the training; now one line naming the option before any work."""
    for uri in (str(tmp_path / "mlruns"), (tmp_path / "mlruns").as_uri()):
        rc, lines = run(["train", str(sim / "g" / "featurepoints.csv"), "--max-iter", "2", "--tracking-uri", uri,
                         "--out", str(tmp_path / "t")])
        one_line(rc, lines, f"--tracking-uri {uri}: MLflow cannot open this store", "sqlite:///")
        assert not (tmp_path / "t").exists()


@pytest.mark.slow   # the training module's import (torch): about 6 CPU s
def test_feature_points_without_validation_name_the_file(sim, tmp_path):
    """feature points copied away from the element set their header names: the refusal names the file and the
    missing element set (it named neither)."""
    fp = tmp_path / "featurepoints.csv"
    fp.write_text((sim / "g" / "featurepoints.csv").read_text())
    (tmp_path / "featurepoints.meta.json").write_text((sim / "g" / "featurepoints.meta.json").read_text())   # its provenance
    rc, lines = run(["train", str(fp), "--max-iter", "2", "--out", str(tmp_path / "t")])
    one_line(rc, lines, f"{fp}: no validation data", "truth_elements.json, is not beside it", "--validation")


def test_an_input_that_is_not_a_regular_file_says_what_it_is(sim, tmp_path):
    """a folder, a device, a FIFO or a symbolic-link loop given as the input: was "no such file" for each."""
    import os
    os.mkfifo(tmp_path / "fifo.csv")
    os.symlink(tmp_path / "b.csv", tmp_path / "a.csv")
    os.symlink(tmp_path / "a.csv", tmp_path / "b.csv")
    el = str(sim / "g" / "truth_elements.json")
    for src, what in ((tmp_path, "is a folder"), ("/dev/zero", "is a device"), (tmp_path / "fifo.csv", "is a FIFO"),
                      (tmp_path / "a.csv", "is a symbolic-link loop"), (tmp_path / "none.csv", "no such file")):
        rc, lines = run(["predict", str(src), "--model", el, "--out", str(tmp_path / "o.csv")])
        one_line(rc, lines, f"{src}: {what}")
        rc, lines = run(["compensate", str(src), "--model", el, "--method", "exact", "--out", str(tmp_path / "c")])
        one_line(rc, lines, f"{src}: {what}")


def test_a_header_without_rows_is_refused(sim, tmp_path):
    """predict on a points file that is a header alone: was exit 0 with "wrote 0 predictions"."""
    p = tmp_path / "p.csv"
    p.write_text("x_mm,z_mm,a_deg\n")
    rc, lines = run(["predict", str(p), "--model", str(sim / "g" / "truth_elements.json"), "--out", str(tmp_path / "o.csv")])
    one_line(rc, lines, f"{p}: no data rows under the header")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.slow   # the arm stack's imports and compilation: about 20 CPU s
def test_an_arm_joint_file_without_rows_is_refused(tmp_path):
    """predict / compensate on an arm with a joint file that is a header alone: was a ValueError traceback (a max over
    zero rows) for both. The calibration: a plain geometric LSQ on 40 simulated UR5 poses (as tests/test_fuzz_commands)."""
    import numpy as np
    from compensation.fields import ARM_FORMAT as MODEL_FORMAT
    from errormap.arm_calibration import fit_plain_lsq
    from errormap.arm_simulate import draw_truth, measure, random_joints
    from errormap.machine import load_machine
    ur5 = load_machine("ur5")
    lo, hi = np.array([-60.0, -120.0, 30.0, -120.0, 40.0, -30.0]), np.array([60.0, -30.0, 140.0, 30.0, 150.0, 30.0])
    geo = fit_plain_lsq(ur5, measure(ur5, draw_truth(ur5, 7), random_joints(lo, hi, 40, [7, 0]), 0.02, [7, 1]))
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "model.json").write_text(json.dumps(
        {"format": MODEL_FORMAT, "machine": {"name": ur5.name, "joints": ur5.joint_columns},
         "kept_stage": "plain geometric LSQ", "geometric": geo.to_dict(), "plain_geometric": geo.to_dict(), "learned": None}))
    q = tmp_path / "q.csv"
    q.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n")
    cal = str(tmp_path / "cal" / "model.json")
    for argv in (["predict", str(q), "--machine", "ur5", "--model", cal, "--allow", "failed-verdict",
                  "--out", str(tmp_path / "o.csv")],
                 ["compensate", str(q), "--machine", "ur5", "--model", cal, "--allow", "failed-verdict",
                  "--out", str(tmp_path / "c")]):
        rc, err = run(argv)
        one_line(rc, err, f"{q}: no data rows under the header (columns q1_deg")
