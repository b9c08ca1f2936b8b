"""Train through a real ``mlflow server`` (own SQLite store and artifact folder in a temp dir: the session's
``mlflow_server``, tests/conftest.py), then load the model back by run id and check its predictions."""
from __future__ import annotations

import numpy as np
import pytest

from errormap.featurepoints import FeaturePoints, grid_axes
from errormap.machine import load_machine

SMOOTH_TOL_UM = 0.1      # as in test_training: LM, 60 iterations, small net, smooth field


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
    # the artifacts went through the server into its own artifact folder (under the run's id), not the repository
    stored = [p for p in (tmp / "art").rglob("weights.npy") if res.run_id in p.parts]
    assert len(stored) == 1
