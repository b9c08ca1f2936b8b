"""The per-input range distance (issue 29, fifth round; a setting, ``DriftSelector(input_range=True)``): ρ also
from each input's exceedance of its own fit range, which a whole-vector distance dilutes when correlated sensors
move together; the model carries it (save / load, update), a file without it reads as before, predictions stay
causal, and the selector's scale can be chosen on the horizon and novelty folds together."""
import json

import numpy as np
import pytest

from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import (RANGE_QUANTILE, SCALE_FOLDS, ChannelFit, DriftModel, DriftSelector,
                                             Feature, distance_weight, feature_matrix, input_range_of, mahalanobis,
                                             range_rho, relative_distance, whitener)
from errormap.diagnosis.drift_update import DriftUpdater
from tests.test_drift_distance import _log as _distance_log

# ρ of the range term is 1 + (u − max)/sd: a few float operations on values of order 10
RHO_ATOL = 1e-12
# inside every input's range the prediction IS the fixed linear model (the same floating-point expression)
SAME_UM = 1e-12
# JSON stores floats with repr precision: the reloaded model reproduces predictions to round-off
JSON_ATOL_UM = 1e-9
CAUSAL_ATOL_UM = 1e-9       # predictions up to t must not move when later samples change (floating point only)
N_SENSORS = 20              # correlated sensors moving together: one principal direction of the whole-vector distance
OUT_SD = 3.0                # the constructed move beyond the range, in fit standard deviations of each sensor


def _correlated(seed=0, n=2000, n_sensors=N_SENSORS):
    """(n, n_sensors) temperatures: one common mode (uniform, spread 1 °C) plus 0.05 °C independent noise each."""
    rng = np.random.default_rng(seed)
    common = rng.uniform(-1.0, 1.0, n)
    return 22.0 + common[:, None] + 0.05 * rng.normal(size=(n, n_sensors))


def test_range_rho_sees_a_correlated_move_the_whole_vector_distance_dilutes():
    U = _correlated()
    ref = input_range_of(U)
    # a row with every sensor OUT_SD fit spreads above its own maximum (a move along the common mode)
    row = (ref["hi"] + OUT_SD * ref["sd"])[None, :]
    expected = 1.0 + OUT_SD
    np.testing.assert_allclose(range_rho(ref, row), [expected], rtol=0, atol=RHO_ATOL)
    whole = relative_distance(U, row)
    assert whole[0] < 1.0 < expected      # inside the whole-vector range, 3 spreads out of every input's own
    both = relative_distance(U, row, input_range=True)
    np.testing.assert_allclose(both, np.maximum(whole, expected), rtol=0, atol=RHO_ATOL)
    # rows inside every range: the term is 0, the distance is the whole-vector one unchanged
    inside = U[::97]
    assert np.all(range_rho(ref, inside) == 0.0)
    np.testing.assert_array_equal(relative_distance(U, inside, input_range=True), relative_distance(U, inside))
    # the largest exceedance counts, below the range too, and one input alone is enough
    one = U[:1].copy()
    one[0, 4] = ref["lo"][4] - 2.0 * ref["sd"][4]
    np.testing.assert_allclose(range_rho(ref, one), [3.0], rtol=0, atol=RHO_ATOL)


def _log():
    """Two temperatures and a speed; from row 600 of 900 temperature a ramps 4 °C out of its range (the speed stays)."""
    return _distance_log(speed_ramp=False)


def _model(log, n_in=600, scale=0.5, with_range=True):
    rows = np.arange(n_in)
    U = np.stack([log.temps_c["a"], log.temps_c["b"], log.speed_rpm], axis=1)
    mu, W = whitener(U[rows])
    d0 = float(np.quantile(mahalanobis(U[rows], mu, W), RANGE_QUANTILE))
    nov = {"inputs": ["temp_a_c", "temp_b_c", "speed_rpm"], "mean": mu.tolist(), "whiten": W.tolist(),
           "range_distance": d0}
    if with_range:
        nov["input_range"] = {k: v.tolist() for k, v in input_range_of(U[rows]).items()}
    base = ([Feature("temp_a_c"), Feature("temp_b_c"), Feature("speed_rpm")], -10.0, np.array([2.5, -1.5, 1e-3]))
    feats = [Feature("temp_a_c", 900.0), Feature("temp_b_c"), Feature("speed_rpm", 1800.0)]
    ch = ChannelFit("test", "", feats, -20.0, np.array([3.5, -2.0, 2e-3]), 1.5, base=base, shrink_scale=scale)
    return DriftModel({"ch1": ch}, {"novelty": nov})


def test_model_shrinks_by_the_larger_distance_and_equals_the_fixed_model_inside():
    log = _log()
    model = _model(log)
    plain = _model(log, with_range=False)
    U = np.stack([log.temps_c["a"], log.temps_c["b"], log.speed_rpm], axis=1)
    rho = model.rho(log)
    np.testing.assert_allclose(rho, np.maximum(plain.rho(log), range_rho(input_range_of(U[:600]), U)),
                               rtol=0, atol=RHO_ATOL)
    fixed = model.predict(log, distance_shrink=False)["ch1"]
    pred = model.predict(log)["ch1"]
    c = model.channels["ch1"]
    bf, ba, bc = c.base
    base = ba + feature_matrix(log, bf) @ bc
    np.testing.assert_allclose(pred, base + distance_weight(rho, c.shrink_scale) * (fixed - base), rtol=0,
                               atol=SAME_UM)
    inside = rho <= 1.0
    assert inside[:600].mean() > 0.9
    np.testing.assert_array_equal(pred[inside], fixed[inside])
    # the ramp leaves a's range: the range term is the larger there, and moves the prediction further to OLS
    late = slice(750, None)
    assert np.all(rho[late] >= plain.rho(log)[late]) and np.any(rho[late] > plain.rho(log)[late])
    assert np.all(np.abs(pred[late] - base[late]) <= np.abs(plain.predict(log)["ch1"][late] - base[late]) + SAME_UM)


def test_json_round_trip_keeps_the_range_and_an_old_file_reads_as_before(tmp_path):
    log = _log()
    model = _model(log)
    model.save(tmp_path / "m.json")
    back = DriftModel.load(tmp_path / "m.json")
    np.testing.assert_allclose(back.predict(log)["ch1"], model.predict(log)["ch1"], rtol=0, atol=JSON_ATOL_UM)
    np.testing.assert_allclose(back.band_um(log)["ch1"], model.band_um(log)["ch1"], rtol=0, atol=JSON_ATOL_UM)
    # a drift_model.json written before the setting existed (no "input_range"): the whole-vector distance only
    obj = json.loads((tmp_path / "m.json").read_text())
    del obj["fitted_on"]["novelty"]["input_range"]
    (tmp_path / "old.json").write_text(json.dumps(obj))
    old = DriftModel.load(tmp_path / "old.json")
    np.testing.assert_allclose(old.predict(log)["ch1"], _model(log, with_range=False).predict(log)["ch1"],
                               rtol=0, atol=JSON_ATOL_UM)


def test_predictions_up_to_t_ignore_later_samples_and_update_without_measurements_is_the_saved_model():
    log = _log()
    model = _model(log)
    before = model.predict(log)["ch1"]
    band = model.band_um(log)["ch1"]
    cut = 700
    late = np.arange(len(log.time_s)) > cut
    altered = DriftLog(log.time_s, {s: np.where(late, v + 5.0, v) for s, v in log.temps_c.items()}, log.disp_um,
                       np.where(late, 12000.0, log.speed_rpm), "<altered>")
    after = model.predict(altered)["ch1"]
    np.testing.assert_allclose(after[:cut + 1], before[:cut + 1], rtol=0, atol=CAUSAL_ATOL_UM)
    np.testing.assert_allclose(model.band_um(altered)["ch1"][:cut + 1], band[:cut + 1], rtol=0, atol=CAUSAL_ATOL_UM)
    assert np.abs(after[cut + 1:] - before[cut + 1:]).max() > 1e-3
    none = DriftUpdater(noise_um=0.3).run(model, log, {"ch1": np.full(len(before), np.nan)})
    np.testing.assert_allclose(none.pred_um["ch1"], before, rtol=0, atol=SAME_UM)
    # with measurements before the ramp only, the updated prediction beyond a's range is still shrunk by the range
    meas = np.full(len(before), np.nan)
    meas[:600:5] = log.disp_um["ch1"][:600:5]
    res = DriftUpdater(noise_um=0.3).run(model, log, {"ch1": meas})
    U = np.stack([log.temps_c["a"], log.temps_c["b"], log.speed_rpm], axis=1)
    out = range_rho(input_range_of(U[:600]), U)
    assert np.any(out > 0)
    assert np.all(res.rho["ch1"][out > 0] >= out[out > 0] - RHO_ATOL)


def test_selector_records_the_range_and_checks_its_settings():
    with pytest.raises(ValueError, match="scale_folds"):
        DriftSelector(scale_folds="ranking").fit(_log())
    assert SCALE_FOLDS[0] == "novelty"          # the default scale folds are unchanged
    log = _log()
    sel = DriftSelector(fit_fraction=0.6, input_range=True, scale_folds="horizon_novelty", n_novelty_folds=2,
                        n_novelty_blocks=6).fit(log)
    ref = sel.model_.meta["novelty"]["input_range"]
    U = np.stack([log.temps_c["a"], log.temps_c["b"], log.speed_rpm], axis=1)[:540]
    np.testing.assert_array_equal(ref["lo"], U.min(axis=0))
    np.testing.assert_array_equal(ref["hi"], U.max(axis=0))
    assert "input_range" not in DriftSelector(fit_fraction=0.6, n_novelty_folds=2,
                                              n_novelty_blocks=6).fit(log).model_.meta["novelty"]


def test_export_carries_the_range_term(tmp_path):
    from compensation.app.cli import main
    from errormap.io import write_csv
    log = _log()
    model = _model(log)
    model.save(tmp_path / "m.json")
    write_csv(tmp_path / "log.csv", {"time_s": log.time_s, "temp_a_c": log.temps_c["a"],
                                     "temp_b_c": log.temps_c["b"], "speed_rpm": log.speed_rpm,
                                     "ch1_um": log.disp_um["ch1"]})
    out = tmp_path / "exp"
    assert main(["export", str(tmp_path / "m.json"), "--format", "drift", "--out", str(out),
                 "--log", str(tmp_path / "log.csv")]) == 0
    rule = json.loads((out / "export.json").read_text())["controller"]["distance_shrink"]
    ref = model.meta["novelty"]["input_range"]
    assert rule["input_range"]["lo"] == ref["lo"] and rule["input_range"]["hi"] == ref["hi"]
    assert rule["input_range"]["sd"] == ref["sd"]
    # a model without the term exports as before (no key)
    _model(log, with_range=False).save(tmp_path / "p.json")
    assert main(["export", str(tmp_path / "p.json"), "--format", "drift", "--out", str(tmp_path / "exp2"),
                 "--log", str(tmp_path / "log.csv")]) == 0
    assert "input_range" not in json.loads((tmp_path / "exp2" / "export.json").read_text())["controller"][
        "distance_shrink"]
