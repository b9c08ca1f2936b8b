"""Per-sample shrinkage toward OLS that grows with the distance of a sample's inputs from the fit data, and the
band that grows with it (issue 29, points 1 and 3): equal to the fixed model inside the fit range, monotone
beyond, causal, kept through the JSON form and the export; and the gate's fallback to OLS on a simulated log
whose future leaves the fit range."""
import numpy as np
import pytest

from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import (RANGE_QUANTILE, ChannelFit, DriftModel, DriftSelector, Feature,
                                               distance_weight, mahalanobis, relative_distance, whitener)
from errormap.diagnosis.drift_sim import simulate_lumped_log

# inside the fit range the shrunk prediction IS the fixed linear model: the same floating-point expression
SAME_UM = 1e-12
# g(ρ) recovered from (pred − base)/(fixed − base): a ratio of ~10 μm differences, float round-off only
RATIO_ATOL = 1e-9
# the JSON form stores floats with repr precision: the reloaded model reproduces predictions to round-off
JSON_ATOL_UM = 1e-9
# the bound on a future outside the fit range: never worse than OLS by more than 5 %
TOLERATED_LOSS = 1.05


def _log(seed=0, n=900, n_in=600, far=4.0, speed_ramp=True):
    """Two temperatures and a speed; rows ≥ ``n_in`` ramp out of the first rows' range (up to ``far`` spreads):
    temperature a, and the speed too when ``speed_ramp`` (else only a leaves its range)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    a = 20 + np.sin(t / 7000.0) + 0.05 * rng.normal(size=n)
    b = 22 + np.cos(t / 5000.0) + 0.05 * rng.normal(size=n)
    sp = 5000 + 2000 * np.sin(t / 3000.0)
    ramp = np.clip((np.arange(n) - n_in) / (n - n_in), 0, 1)
    a = a + far * ramp
    sp = sp + 3000 * far * ramp * speed_ramp
    d = 3 * (a - 20) - 2 * (b - 22) + 1e-3 * (sp - 5000)
    return DriftLog(t, {"a": a, "b": b}, {"ch1": d}, sp, "<test>")


def _model(log, n_in=600, scale=0.5):
    rows = np.arange(n_in)
    U = np.stack([log.temps_c["a"], log.temps_c["b"], log.speed_rpm], axis=1)
    mu, W = whitener(U[rows])
    d0 = float(np.quantile(mahalanobis(U[rows], mu, W), RANGE_QUANTILE))
    base = ([Feature("temp_a_c"), Feature("temp_b_c"), Feature("speed_rpm")], -10.0, np.array([2.5, -1.5, 1e-3]))
    feats = [Feature("temp_a_c", 900.0), Feature("temp_b_c"), Feature("speed_rpm", 1800.0)]
    meta = {"novelty": {"inputs": ["temp_a_c", "temp_b_c", "speed_rpm"], "mean": mu.tolist(), "whiten": W.tolist(),
                        "range_distance": d0}}
    ch = ChannelFit("test", "", feats, -20.0, np.array([3.5, -2.0, 2e-3]), 1.5, base=base, shrink_scale=scale)
    return DriftModel({"ch1": ch}, meta)


def test_distance_weight_is_one_inside_the_range_and_decreases_beyond():
    rho = np.linspace(0, 6, 200)
    for s in (2.0, 1.0, 0.25):
        g = distance_weight(rho, s)
        assert np.all(g[rho <= 1] == 1.0)
        assert np.all(np.diff(g) <= 0) and np.all(np.diff(g[rho > 1]) < 0)
        assert 0 < g[-1] < 1
    assert np.all(distance_weight(rho, np.inf) == 1.0)


def test_shrinkage_equals_the_fixed_model_inside_the_range_and_is_monotone_in_distance():
    log = _log()
    m = _model(log)
    rho = m.rho(log)
    inside = rho <= 1
    assert inside.sum() > 300 and (rho > 2).sum() > 50          # the log has both cases
    pred = m.predict(log)["ch1"]
    fixed = m.predict(log, distance_shrink=False)["ch1"]
    bf, ba, bc = m.channels["ch1"].base
    from errormap.diagnosis.drift_models import feature_matrix
    base = ba + feature_matrix(log, bf) @ bc
    np.testing.assert_allclose(pred[inside], fixed[inside], atol=SAME_UM, rtol=0)
    out = ~inside & (np.abs(fixed - base) > 0.1)
    g = (pred[out] - base[out]) / (fixed[out] - base[out])
    np.testing.assert_allclose(g, distance_weight(rho[out], 0.5), atol=RATIO_ATOL, rtol=0)
    order = np.argsort(rho[out])
    assert np.all(np.diff(g[order]) <= RATIO_ATOL)              # more distant: closer to OLS
    # the band grows as max(1, ρ)
    band = m.band_um(log)["ch1"]
    np.testing.assert_allclose(band, 1.5 * np.maximum(1.0, rho), atol=SAME_UM, rtol=0)


def test_json_round_trip_keeps_the_rule():
    log = _log()
    m = _model(log)
    back = DriftModel.from_json(m.to_json())
    assert back.channels["ch1"].shrink_scale == 0.5
    np.testing.assert_allclose(back.predict(log)["ch1"], m.predict(log)["ch1"], atol=JSON_ATOL_UM, rtol=0)
    np.testing.assert_allclose(back.band_um(log)["ch1"], m.band_um(log)["ch1"], atol=JSON_ATOL_UM, rtol=0)


def test_predictions_and_band_up_to_t_ignore_later_samples():
    log = _log()
    m = _model(log)
    k = 700
    alt = DriftLog(log.time_s, {s: v.copy() for s, v in log.temps_c.items()}, {"ch1": log.disp_um["ch1"].copy()},
                   log.speed_rpm.copy(), "<alt>")
    alt.temps_c["a"][k + 1:] += 30.0                            # far out of range after t
    alt.speed_rpm[k + 1:] *= 3
    for f in (lambda mm, lg: mm.predict(lg)["ch1"], lambda mm, lg: mm.band_um(lg)["ch1"]):
        np.testing.assert_array_equal(f(m, log)[:k + 1], f(m, alt)[:k + 1])
    assert not np.allclose(m.predict(log)["ch1"][k + 1:], m.predict(alt)["ch1"][k + 1:])


def test_relative_distance_is_one_at_the_fit_datas_range_quantile():
    rng = np.random.default_rng(3)
    U = rng.normal(size=(2000, 4)) * [1.0, 10.0, 1000.0, 0.1]   # units of very different size
    rho = relative_distance(U, U)
    assert abs(np.mean(rho <= 1) - RANGE_QUANTILE) < 1e-3
    # standardised: a shift of 5 spreads on the smallest-unit input counts as much as on the largest
    far_small = relative_distance(U, U[:1] + [0, 0, 0, 0.5])
    far_large = relative_distance(U, U[:1] + [0, 0, 5000.0, 0])
    assert far_small[0] > 1 and far_large[0] > 1


@pytest.mark.slow  # a whole selection on a 40 h log (~10 CPU s)
def test_gate_falls_back_to_ols_where_nothing_beats_it_on_a_future_leaving_the_range():
    """Displacement exactly linear in the logged inputs + white noise: no flexible family can be clearly
    better, so every channel must come back as OLS (or within the issue's bound of it) on the shifted future."""
    cols = simulate_lumped_log(4, hours=40.0, dt_s=120.0, shift_at=0.6, n_dropouts=0)
    cols.pop("_truth")
    temps = {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")}
    rng = np.random.default_rng(11)
    names = sorted(temps)
    disp = {}
    for j in range(2):
        w = rng.normal(0, 2.0, len(names))
        disp[f"c{j}"] = sum(wi * (temps[s] - temps[s].mean()) for wi, s in zip(w, names)) \
            + 1e-3 * cols["speed_rpm"] + rng.normal(0, 0.5, len(cols["time_s"]))
    log = DriftLog(cols["time_s"], temps, disp, cols["speed_rpm"], "<linear>")
    sel = DriftSelector(fit_fraction=0.6).fit(log)
    _, hold = sel.split(log)
    assert np.median(sel.model_.rho(log)[hold]) > 1              # the future does leave the fit range
    rep = sel.report(log)
    for ch, r in rep.items():
        assert r["model"] == "ols", (ch, r["model"], sel.gate_[ch].get(r["model"]))
        assert r["rms_after_um"] <= TOLERATED_LOSS * r["rms_ols_um"]
