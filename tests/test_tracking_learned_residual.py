"""The closed loop's learned residual tracked in MLflow (training.tracking.log_learned_residual)."""
import json

import numpy as np
import pytest

from compensation.hybrid import LEARNED_FAMILIES, LearnedResidual, learned_stage
from errormap.machine import load_machine
from errormap.chain_truth import random_axes
from test_hybrid import WORK_FRAME

SEED = 0
N_CHECKS, N_FIT = 300, 180
NOISE_UM = 1.0
BUMP_UM = 8.0            # a local bump of the Y error (the simulator's 'bump' default amplitude)
TOL_EXACT_UM = 1e-12     # the JSON the run holds predicts what the in-memory residual predicts (repr() floats)


def _bump(machine, axes):
    lo = np.array([machine.strokes["x_mm"][0], machine.strokes["z_mm"][0]])
    span = np.array([np.ptp(machine.strokes["x_mm"]), np.ptp(machine.strokes["z_mm"])])
    u = (axes[:, :2] - lo) / span
    g = BUMP_UM * np.exp(-0.5 * ((u[:, 0] - 0.6) / 0.18) ** 2 - 0.5 * ((u[:, 1] - 0.4) / 0.18) ** 2)
    return np.stack([np.zeros_like(g), g, np.zeros_like(g)], axis=1)


@pytest.fixture(scope="module")
def kept():
    m = load_machine(None, expect_kind="grinder")
    rng = np.random.default_rng(SEED)
    axes = random_axes(m, N_CHECKS, rng)
    r = _bump(m, axes) + NOISE_UM * rng.standard_normal(axes.shape)
    # the work frame only (test_hybrid.WORK_FRAME): it wins the two-frame comparison here (gp_matern52 in both), the
    # same stage bits but the candidates' table, 6.6 CPU s instead of 12.3
    learned, stage = learned_stage(m, r, axes, np.arange(N_FIT), np.arange(N_FIT, N_CHECKS), seed=SEED,
                                   frames=WORK_FRAME)
    assert learned is not None, stage["learned"]["why"]  # the bump is well above the noise: kept
    return learned, stage


@pytest.mark.slow  # over the 5 CPU s tier limit (MLflow store creation and logging)
def test_kept_learned_residual_is_a_run_with_its_cv_table_family_and_json(kept, tmp_path):
    from mlflow.tracking import MlflowClient

    from training.tracking import load_learned_residual_doc, log_learned_residual
    learned, stage = kept
    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    model_doc = {"format": "volcomp-diagnosed-model/1", "stage": "learned_residual",
                 "learned_residual": learned.to_dict()}
    rid = log_learned_residual(stage, learned.to_dict(), model_doc=model_doc, tracking_uri=uri,
                               tags={"checks": "checks.csv"})
    run = MlflowClient(tracking_uri=uri).get_run(rid)
    assert run.info.status == "FINISHED"
    assert run.data.params["family"] == learned.chosen == stage["learned"]["family"]
    assert run.data.params["kept"] == "True" and run.data.tags["kind"] == "learned_residual"
    assert run.data.params["output_frame"] == learned.frame == stage["learned"]["output_frame"]
    m = run.data.metrics
    assert m["held_out.rms_um"] == pytest.approx(stage["held_out"]["rms_um"], rel=0, abs=0)
    assert m["learned.held_out_gain_z"] == pytest.approx(stage["learned"]["held_out_gain_z"], rel=0, abs=0)
    # every family of the CV table has its figures logged
    for fam in stage["learned"]["cv_table"]:
        assert any(k.startswith(f"cv_table.{fam}.") for k in m), fam
    names = {a.path for a in MlflowClient(tracking_uri=uri).list_artifacts(rid)}
    assert {"learned_residual.json", "stage.json", "model.json"} <= names
    # the logged JSON is the learned residual: it loads back and predicts the same
    back = LearnedResidual.from_dict(load_learned_residual_doc(rid, tracking_uri=uri))
    x = random_axes(load_machine(None, expect_kind="grinder"), 50, np.random.default_rng(3))
    assert np.abs(back.predict(x) - learned.predict(x)).max() <= TOL_EXACT_UM
    json.dumps(stage, default=str)  # the stage summary is what stage.json holds


def test_missing_run_is_one_clear_error(tmp_path):
    from errormap.io import InputError
    from training.tracking import load_learned_residual_doc
    uri = f"sqlite:///{tmp_path / 'store' / 'mlflow.db'}"
    with pytest.raises(InputError, match="no learned residual"):
        load_learned_residual_doc("0" * 32, tracking_uri=uri)


@pytest.mark.slow
def test_diagnose_track_logs_the_kept_stage(bump_user_path):
    """sweeps → simulate (bump) → identify → diagnose --track (the shared run, tests/shared_runs.py): the
    kept learned residual is a run whose JSON is the one model.json holds."""
    from training.tracking import load_learned_residual_doc
    d, uri = bump_user_path.root / "d", bump_user_path.extra["uri"]
    s = json.loads((d / "diagnosis.json").read_text())
    model = json.loads((d / "model.json").read_text())
    assert s["kept_stage"] == "learned_residual"
    rid = s["learned_residual"]["mlflow_run_id"]
    assert model["mlflow_run_id"] == rid and f"learned residual logged as MLflow run {rid}" in bump_user_path.out
    assert load_learned_residual_doc(rid, tracking_uri=uri) == json.loads(json.dumps(model["learned_residual"]))
    # the family chosen by validation, named; the shipped stage estimated on all 800 checks after the
    # choice, the held-out figures the validated ones (issue 28: refit after selection)
    lr = s["learned_residual"]
    assert lr["families_compared"] == list(LEARNED_FAMILIES) and lr["family"] in lr["cv_table"]
    assert lr["family_name"].split(" ")[0] in ("Gaussian", "deep")
    assert lr["shipped"]["estimated_on_checks"] == 800 and lr["shipped"]["base_refit_on_all_checks"] is True
    assert s["refit_on_all_checks"]["checks"] == 800
    assert s["held_out_rms_um"] == s["stages"]["learned_residual"]["held_out"]["rms_um"]
    assert model["learned_family"]["family"] == lr["family"] and model["learned_family"]["estimated_on_checks"] == 800
    assert model["learned_family"]["name"] == lr["family_name"]
