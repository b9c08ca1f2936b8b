"""A machine-tool chain's network recorded in MLflow like the grinder's (always: ``--tracking-uri``, else the
default store), and used from there (``predict`` / ``compensate --machine ... --model runs:/<id>/model``)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.io import read_table
from training.model import MLPField

from test_chain_compensate import MILL_PROGRAM
from test_chain_train import smooth_mill  # noqa: F401  (fixture: a smooth mill's truth and 7x7x7 feature points)

CSV_REL = 1e-8
"""The network loaded from the MLflow run and from the run folder are the same files; the predictions CSV
holds 9 significant digits (%.9g: at most 5e-9 relative per value)."""
TOL_MODEL_RESIDUAL_EXACT_UM = 1e-6
"""As tests/test_chain_train.py: the exact chain solver on a network field reaches round-off."""


@pytest.mark.slow
def test_chain_network_is_tracked_by_default_like_the_grinders(smooth_mill, tmp_path, capsys, monkeypatch):  # noqa: F811
    """No --tracking-uri: the run goes to the default store ($MLFLOW_TRACKING_URI, else runs/mlflow.db), as the
    grinder's train does; --run-name names it there."""
    from mlflow.tracking import MlflowClient
    _, fp = smooth_mill
    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    run = tmp_path / "r"
    assert main(["train", str(fp), "--out", str(run), "--hidden", "10,10", "--max-iter", "100", "--seed", "0",
                 "--physics", "none", "--run-name", "default-store"]) == 0
    out = capsys.readouterr().out
    m = json.loads((run / "metrics.json").read_text())
    assert m["tracking_uri"] == uri and f"--model runs:/{m['run_id']}/model --tracking-uri {uri}" in out
    r = MlflowClient(tracking_uri=uri).get_run(m["run_id"])
    assert r.info.run_name == "default-store" and r.data.tags["machine"] == "mill-xyz"


@pytest.mark.slow
def test_chain_network_is_tracked_and_used_from_mlflow(smooth_mill, tmp_path, capsys):  # noqa: F811
    from mlflow.tracking import MlflowClient
    _, fp = smooth_mill
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    run = tmp_path / "run"
    assert main(["train", str(fp), "--out", str(run), "--hidden", "10,10", "--max-iter", "100", "--seed", "0",
                 "--physics", "none", "--tracking-uri", uri, "--run-name", "mill-net"]) == 0
    doc = json.loads((run / "metrics.json").read_text())
    rid = doc["run_id"]
    r = MlflowClient(tracking_uri=uri).get_run(rid)
    assert r.info.run_name == "mill-net" and r.info.status == "FINISHED"
    assert r.data.tags["machine"] == "mill-xyz"
    assert r.data.params["machine"] == "mill-xyz" and r.data.params["inputs"] == "x_mm,y_mm,z_mm"
    for k in ("val_rms_um", "val_max_um", "baseline_ols_val_rms_um", "train_max_um"):   # the baseline beside it
        assert r.data.metrics[k] == pytest.approx(doc[k], rel=1e-12)
    assert r.data.metrics["val_rms_um"] < r.data.metrics["baseline_ols_val_rms_um"]
    capsys.readouterr()
    # predict from the run = predict from the folder
    pts = tmp_path / "pts.csv"
    a = np.random.default_rng(7).uniform([0, 0, -400], [600, 400, 0], (20, 3))
    pts.write_text("x_mm,y_mm,z_mm\n" + "".join(f"{x:.17g},{y:.17g},{z:.17g}\n" for x, y, z in a))
    assert main(["predict", "--machine", "mill-xyz", "--model", f"runs:/{rid}/model", "--tracking-uri", uri,
                 str(pts), "--out", str(tmp_path / "p.csv")]) == 0
    t = read_table(tmp_path / "p.csv")
    got = np.stack([t.float(c) for c in ("dx_um", "dy_um", "dz_um")], axis=1)
    want = MLPField.load(run / "model").predict(a)
    assert np.all(np.abs(got - want) <= CSV_REL * np.abs(want))
    # compensate from the run (exact: model residual to round-off)
    assert main(["compensate", str(MILL_PROGRAM), "--machine", "mill-xyz", "--model", rid, "--tracking-uri", uri,
                 "--method", "exact", "--out", str(tmp_path / "c"), "--work-offsets", "machine"]) == 0  # G54 = machine
    e = json.loads((tmp_path / "c" / "compensate_summary.json").read_text())["files"][0]
    assert e["failures"] == 0 and e["model_max_um"] <= TOL_MODEL_RESIDUAL_EXACT_UM
    capsys.readouterr()
    # the grinder (no --machine) refuses the chain network in one line, by its config's format key
    gpts = tmp_path / "gpts.csv"
    gpts.write_text("x_mm,z_mm,a_deg\n50,0,10\n")
    assert main(["predict", "--model", rid, "--tracking-uri", uri, str(gpts), "--out", str(tmp_path / "g.csv")]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines()
           if not ln.startswith("Downloading artifacts")]   # MLflow's own download progress
    assert len(err) == 1 and "key 'inputs'" in err[0] and "x_mm, y_mm, z_mm" in err[0] and not (tmp_path / "g.csv").exists()
