"""Drift deployed on every row: ``DriftSelector(deploy=True)`` / ``volcomp diagnose --drift --deploy`` validates on the
split, then refits the chosen candidates on the whole log; the validation figures do not move."""

import json

import numpy as np
import pytest

from compensation.app.cli import main
from errormap.diagnosis.drift_models import (DriftSelector, GreyBoxFamily, OLSFamily, ThermalNNFamily, blend_with_ols)
from errormap.diagnosis.drift_sim import simulate_lumped_log
from errormap.io import write_csv
from tests.test_drift_models import _frame

# the deployed fit and a direct fit on all rows run the same arithmetic on the same rows: floating point only
SAME_FIT_RTOL = 1e-12
# lumped seed 2, 24 h at 120 s: the grey-box family is chosen for ch1 (blended toward OLS), OLS elsewhere
SEED, HOURS, DT_S = 2, 24.0, 120.0


def _families():
    return [OLSFamily(), GreyBoxFamily(), ThermalNNFamily()]


@pytest.fixture(scope="module")
def case():
    cols = simulate_lumped_log(SEED, hours=HOURS, dt_s=DT_S, n_dropouts=0)
    cols.pop("_truth")
    log = _frame(cols)
    plain = DriftSelector(fit_fraction=0.6, families=_families()).fit(log)
    deployed = DriftSelector(fit_fraction=0.6, families=_families(), deploy=True).fit(log)
    return cols, log, plain, deployed


def test_the_deployed_model_is_the_chosen_candidate_fitted_on_every_row(case):
    _, log, plain, sel = case
    assert plain.deployed_ is None
    rows = np.arange(len(log.time_s))
    assert sel.deployed_.meta["fit_rows"] == len(rows)
    assert sel.deployed_.meta["validated_on_rows"] == len(sel.split(log)[0])
    assert any(f != "ols" for f, _ in sel.chosen_.values())   # a blended non-OLS candidate is covered
    fams = {f.name: f for f in _families()}
    for ch, (f, hy) in sel.chosen_.items():
        ols = fams["ols"].fit(log, [ch], rows, {})[ch][""]
        feats, a, b = blend_with_ols(fams[f].fit(log, [ch], rows, {})[ch][hy], ols, sel.shrink_[ch])
        got = sel.deployed_.channels[ch]
        assert [x.key for x in got.features] == [x.key for x in feats]
        np.testing.assert_allclose(got.coef, b, rtol=SAME_FIT_RTOL, atol=0)
        assert got.intercept_um == pytest.approx(a, rel=SAME_FIT_RTOL)
        assert got.shrink_scale == sel.scale_[ch] and got.band95_um == sel.model_.channels[ch].band95_um
    # and it differs from the validated model (fitted on the split's first part) where rows were added
    ch = next(iter(sel.chosen_))
    assert not np.allclose(sel.deployed_.channels[ch].coef, sel.model_.channels[ch].coef)


def test_deploy_leaves_every_validation_figure_unchanged(case):
    _, log, plain, sel = case
    assert plain.chosen_ == sel.chosen_ and plain.shrink_ == sel.shrink_ and plain.scale_ == sel.scale_
    assert json.dumps(plain.report(log), sort_keys=True) == json.dumps(sel.report(log), sort_keys=True)
    for ch in plain.chosen_:
        np.testing.assert_array_equal(plain.model_.channels[ch].coef, sel.model_.channels[ch].coef)


@pytest.mark.slow  # two whole default selections through the CLI
def test_diagnose_drift_deploy_records_both(case, tmp_path):
    cols = case[0]
    write_csv(tmp_path / "log.csv", cols)
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["diagnose", "--drift", str(tmp_path / "log.csv"), "--out", str(a)]) == 0
    assert main(["diagnose", "--drift", str(tmp_path / "log.csv"), "--out", str(b), "--deploy"]) == 0
    da, db = (json.loads((d / "diagnosis.json").read_text()) for d in (a, b))
    assert da["channels"] == db["channels"] and "deployed" not in da
    n = len(cols["time_s"])
    dep = db["deployed"]
    assert dep["rows_used"] == n == dep["rows_in_log"] and dep["validated_on_rows"] == round(0.6 * n)
    assert set(dep["channels"]) == set(db["channels"])
    for ch, c in dep["channels"].items():
        assert c["candidate"] == db["channels"][ch]["model"]
    ma, mb = (json.loads((d / "drift_model.json").read_text()) for d in (a, b))
    assert ma["fitted_on"]["fit_rows"] == round(0.6 * n) and mb["fitted_on"]["fit_rows"] == n
