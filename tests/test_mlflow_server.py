"""Train through a real ``mlflow server`` (own SQLite store and artifact folder in a temp dir),
then load the model back by run id and check its predictions."""
from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import stop_process_group, wait_until_serving
from errormap.featurepoints import FeaturePoints, grid_axes
from errormap.machine import load_machine

STARTUP_LIMIT_S = 120.0  # bounded poll for the server to answer /health
SMOOTH_TOL_UM = 0.1      # as in test_training: LM, 60 iterations, small net, smooth field


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _mlflow_exe() -> str:
    exe = Path(sys.executable).with_name("mlflow")
    return str(exe) if exe.is_file() else (shutil.which("mlflow") or "mlflow")


@pytest.fixture
def mlflow_server(tmp_path):
    port = _free_port()
    log = open(tmp_path / "server.log", "wb")
    cmd = [_mlflow_exe(), "server", "--backend-store-uri", f"sqlite:///{tmp_path / 'db.sqlite'}",
           "--artifacts-destination", str(tmp_path / "art"), "--serve-artifacts",
           "--host", "127.0.0.1", "--port", str(port), "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                            env={**os.environ, "MLFLOW_TRACKING_URI": ""})
    url = f"http://127.0.0.1:{port}"
    try:
        wait_until_serving(proc, url + "/health", STARTUP_LIMIT_S, tmp_path / "server.log", "mlflow server")
        yield url, tmp_path
    finally:
        # the server runs in its own session: end exactly that process group
        stop_process_group(proc)
        log.close()


@pytest.mark.slow
def test_train_through_a_real_tracking_server_and_load_by_run_id(mlflow_server):
    from training.tracking import load_field
    from training.trainers import fit_field
    url, tmp = mlflow_server
    machine = load_machine(None)
    axes = grid_axes(machine, 6)
    x, z, a = axes[:, 0] / 200.0, axes[:, 1] / 60.0, np.deg2rad(axes[:, 2])
    e = np.column_stack([3.0 * x + 2.0 * z**2, 4.0 * np.cos(a) + x, 2.0 * np.sin(a) * z - x * z])
    fp = FeaturePoints(axes, e, {"machine": machine.name})
    from errormap.threads import limit_threads
    with limit_threads(1):
        res = fit_field(fp, max_time_s=120, validation=(axes, e), tracking_uri=url, quiet=True, max_iter=60,
                        hidden=(10, 10), run_name="server-test")
    assert res.metrics["train_max_um"] <= SMOOTH_TOL_UM
    loaded = load_field(res.run_id, tracking_uri=url)
    pts = np.random.default_rng(0).random((50, 3)) * [200.0, 60.0, 360.0]
    assert np.array_equal(loaded.predict(pts), res.field.predict(pts))
    # the artifacts went through the server into its own artifact folder, not the repository
    stored = list((tmp / "art").rglob("weights.npy"))
    assert len(stored) == 1
