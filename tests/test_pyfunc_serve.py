"""The learned field as an MLflow pyfunc model (issue 20): a tracked fit's ``model/`` artifact is
served by ``mlflow models serve`` on 127.0.0.1 and answers with the predictions ``volcomp
predict`` writes for the same points; its signature names the axis and error columns."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import free_port, stop_process_group, wait_until_serving
from errormap.featurepoints import FeaturePoints, grid_axes
from errormap.io import read_table, write_csv
from errormap.machine import builtin_machine_path, load_machine

ROOT = Path(__file__).resolve().parents[1]
STARTUP_LIMIT_S = 180.0  # bounded poll for the scoring server to answer /ping (a loaded 2-core machine)
CSV_DIGITS = "%.9g"      # volcomp predict writes 9 significant digits: the served float64 is compared at that


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    from training.trainers import fit_field
    tmp = tmp_path_factory.mktemp("pyfunc")
    store = f"sqlite:///{tmp / 'db.sqlite'}"
    machine = load_machine(None)
    axes = grid_axes(machine, 4)
    x, z, a = axes[:, 0] / 200.0, axes[:, 1] / 60.0, np.deg2rad(axes[:, 2])
    e = np.column_stack([3.0 * x + 2.0 * z**2, 4.0 * np.cos(a) + x, 2.0 * np.sin(a) * z - x * z])
    meta = {"machine": machine.name, "machine_file": str(builtin_machine_path())}  # as simulate records it
    res = fit_field(FeaturePoints(axes, e, meta), max_time_s=120, validation=(axes, e),
                    tracking_uri=store, quiet=True, max_iter=10, hidden=(6, 6), run_name="pyfunc-test")
    return res, store, tmp


@pytest.mark.slow
def test_pyfunc_model_has_signature_example_and_machine(tracked):
    import mlflow.pyfunc
    res, store, tmp = tracked
    from mlflow.artifacts import download_artifacts
    local = Path(download_artifacts(f"runs:/{res.run_id}/model", dst_path=str(tmp / "dl"), tracking_uri=store))
    assert {"MLmodel", "config.json", "scalers.json", "weights.npy", "machine.toml"} <= {p.name for p in local.iterdir()}
    assert (local / "machine.toml").read_bytes() == builtin_machine_path().read_bytes()  # data made on the built-in grinder
    pm = mlflow.pyfunc.load_model(str(local))
    sig = pm.metadata.signature
    assert sig.inputs.input_names() == ["x_mm", "z_mm", "a_deg"]
    assert [c.name for c in sig.outputs.inputs] == ["dx_um", "dy_um", "dz_um"]
    assert pm.metadata.saved_input_example_info is not None
    import pandas as pd
    pts = np.random.default_rng(1).random((20, 3)) * [200.0, 60.0, 360.0]
    out = pm.predict(pd.DataFrame(pts, columns=["x_mm", "z_mm", "a_deg"]))
    assert np.array_equal(out.to_numpy(), res.field.predict(pts))  # the same float64 numbers


@pytest.mark.slow
def test_served_model_equals_volcomp_predict(tracked):
    res, store, tmp = tracked
    pts = np.random.default_rng(2).random((25, 3)) * [200.0, 60.0, 360.0]
    write_csv(tmp / "pts.csv", {"x_mm": pts[:, 0], "z_mm": pts[:, 1], "a_deg": pts[:, 2]})
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MLFLOW_TRACKING_URI": store,
           # the scoring server is started as `uvicorn`, looked up on PATH: this interpreter's bin first
           "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])}
    subprocess.run([sys.executable, "-m", "compensation.app.cli", "predict", "--model", res.run_id, "--tracking-uri", store,
                    str(tmp / "pts.csv"), "--out", str(tmp / "pred.csv")], check=True, env=env, cwd=tmp,
                   capture_output=True, timeout=300)
    t = read_table(tmp / "pred.csv")
    # the CSV round trip of the inputs is what both sides see
    axes = np.stack([t.float(c) for c in ("x_mm", "z_mm", "a_deg")], axis=1)
    port = free_port()
    exe = Path(sys.executable).with_name("mlflow")
    log = open(tmp / "serve.log", "wb")
    proc = subprocess.Popen([str(exe), "models", "serve", "-m", f"runs:/{res.run_id}/model", "--env-manager", "local",
                             "-h", "127.0.0.1", "-p", str(port)], stdout=log, stderr=subprocess.STDOUT, env=env,
                            cwd=tmp, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_until_serving(proc, url + "/ping", STARTUP_LIMIT_S, tmp / "serve.log", "mlflow models serve")
        body = json.dumps({"dataframe_split": {"columns": ["x_mm", "z_mm", "a_deg"], "data": axes.tolist()}}).encode()
        req = urllib.request.Request(url + "/invocations", data=body, headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=60) as r:
            served = json.loads(r.read())["predictions"]
    finally:
        stop_process_group(proc)
        log.close()
    got = np.array([[row[c] for c in ("dx_um", "dy_um", "dz_um")] for row in served])
    assert got.shape == (25, 3)
    for j, c in enumerate(("dx_um", "dy_um", "dz_um")):
        assert [CSV_DIGITS % v for v in got[:, j]] == t.raw(c)
    np.testing.assert_array_equal(got, res.field.predict(axes))
