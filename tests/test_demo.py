"""``volcomp demo`` end to end with tiny settings."""
import json

import numpy as np
import pytest


EXACT_MODEL_UM = 1e-3
"""The exact solver's model residual on the compensated program (measured 1.7e-8 μm; 1e-3 μm is its tolerance
class, far below any machine error)."""
REQUIRED = {"model_max_um", "model_mean_sq_um2", "true_max_um", "seconds", "points"}


@pytest.mark.slow
def test_demo_tiny_end_to_end(tiny_demo):
    """The tiny demo run (tests/shared_runs.py, shared with the demo page's rendering check)."""
    out = tiny_demo.root / "demo"
    printed = tiny_demo
    assert "report.html" in printed.out and "per-point GA on 3 of 24" in printed.err
    for name in ("report.html", "metrics.json", "residuals.csv", "residuals_ga.csv", "demo.json",
                 "sim/truth_elements.json", "sim/featurepoints.csv", "flute.nc", "compensated/flute.nc",
                 "compensated/compensate_summary.json"):
        assert (out / name).is_file(), name
    # the GA ran on 3 of 24 points: its rows alone in residuals_ga.csv, no NaN anywhere
    from errormap.io import read_table
    full, ga = read_table(out / "residuals.csv"), read_table(out / "residuals_ga.csv")
    assert len(full) == 24 and len(ga) == 3 and not any(c.startswith("ga_") for c in full.names)
    assert all(np.isfinite(t.float(c)).all() for t in (full, ga) for c in t.names)
    # the demo's program through compensate (exact, the trained model): every move solved to the model
    summ = json.loads((out / "compensated" / "compensate_summary.json").read_text())
    f = summ["files"][0]
    assert summ["method"] == "exact" and f["format"] == "gcode" and f["failures"] == 0
    assert f["model_max_um"] < EXACT_MODEL_UM and "compensated program:" in printed.out
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["methods"]) == {"traditional", "ga", "batched-ga", "exact"}
    for name, v in m["methods"].items():
        assert REQUIRED <= set(v), name
    assert m["methods"]["ga"]["points"] == 3 and m["methods"]["exact"]["points"] == 24
    # the page and metrics.json state the budget used; demo.json times every stage
    assert "3 of 24 points solved" in m["budget"]["per-point ga"]
    assert f"ran {m['training']['metrics']['iterations']} iterations" in m["budget"]["training"]
    assert "budget: training" in (out / "report.html").read_text()
    stages = json.loads((out / "demo.json").read_text())["stages"]
    assert set(stages) == {"simulate", "train", "compensate", "program", "report"}
    assert all(v["wall_s"] >= 0 and v["cpu_s"] >= 0 for v in stages.values())
    # the exact solver satisfies its own field far better than the traditional one-shot
    assert m["methods"]["exact"]["model_max_um"] < m["methods"]["traditional"]["model_max_um"]
    assert "MODEL" in (out / "report.html").read_text()


def test_report_logs_to_the_default_store_when_no_uri_is_given(tmp_path, monkeypatch):
    """With no --tracking-uri the demo trains into the default store; the report must go to
    the same run there (it used to look in MLflow's own default and not find the run)."""
    from mlflow.tracking import MlflowClient

    from compensation.app.workflows.demo import log_to_mlflow
    uri = f"sqlite:///{tmp_path / 'store.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    client = MlflowClient(uri)
    run_id = client.create_run(client.create_experiment("t", artifact_location=str(tmp_path / "art"))).info.run_id
    files = {}
    for k in ("html", "metrics", "residuals"):
        files[k] = tmp_path / f"{k}.txt"
        files[k].write_text(k)
    log_to_mlflow(run_id, None, files, {"methods": {"exact": {"model_max_um": 1e-9, "seconds": 0.1}}})
    assert sorted(a.path for a in client.list_artifacts(run_id, "report")) == [
        "report/html.txt", "report/metrics.txt", "report/residuals.txt"]
    assert client.get_run(run_id).data.metrics["report.exact.model_max_um"] == 1e-9
