"""The distance rule on each channel's OWN features, the band calibrated on folds, and the distance rule in
`--update` predictions (issue 29): a model extrapolates in what it computes from — a slow filtered state can
leave its fit range while every raw input stays inside — so a channel's ρ is the larger of the raw inputs' and
its features'; the band's scale is a split-conformal quantile of fold residuals; after each Kalman update the
distance is measured from the fit data plus the measurements seen so far, causally."""
import numpy as np
import pytest

from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import (RANGE_QUANTILE, ChannelFit, DriftModel, Feature, conformal_quantile,
                                               distance_weight, feature_matrix, feature_novelty, fit_ols,
                                               mahalanobis, whitener)
from errormap.diagnosis.drift_update import DriftUpdater, RunningReference

# the shrunk prediction inside the range IS the fixed linear model; g recovered from a ratio of ~μm differences
SAME_UM = 1e-12
RATIO_ATOL = 1e-9
# the JSON form stores floats with repr precision: the reloaded model reproduces predictions to round-off
JSON_ATOL_UM = 1e-9
# the running reference (pinv of W·Wᵀ, then Welford) against the whitener on the concatenated rows: the same
# covariance up to floating-point round-off of a well-conditioned 3×3 problem
REFERENCE_RTOL = 1e-8
NOISE_UM = 0.2
MEASURE_EVERY = 5            # rows between on-machine measurements (5 min at 60 s)
# after the step the updated error must come back near the measurement noise (within 2 σ RMS over the last
# quarter: the random walk keeps the filter alert); the saved model's error stays at the step's size (≥ 5 σ)
CONVERGED_SIGMA = 2.0
STEP_SIGMA = 5.0
CAUSAL_ATOL_UM = 1e-9
TAU_SLOW_S = 10800.0
RHO_LEARNED = 0.5            # the updated distance in a measured regime: at most half the saved model's


def _slow_state_log(seed=0, n=1200, n_fit=700):
    """Input a oscillates ±1 °C every 30 min during the fit, then holds at 20.8 °C (inside its raw range): its
    3 h lag, near 20 °C throughout the fit, climbs toward 20.8 — out of ITS range. b drifts slowly throughout."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 60.0
    a = 20 + np.sin(2 * np.pi * t / 1800.0) + 0.02 * rng.normal(size=n)
    a[n_fit:] = 20.8 + 0.02 * rng.normal(size=n - n_fit)
    b = 22 + 0.5 * np.cos(t / 5000.0) + 0.02 * rng.normal(size=n)
    log = DriftLog(t, {"a": a, "b": b}, {}, None, "<slow>")
    return log, np.arange(n_fit)


def _slow_state_model(log, fit, scale=0.5):
    raw = [Feature("temp_a_c"), Feature("temp_b_c")]
    own = [Feature("temp_a_c"), Feature("temp_a_c", TAU_SLOW_S), Feature("temp_b_c")]
    U = feature_matrix(log, raw)
    F = feature_matrix(log, own)
    d = F @ np.array([1.0, 8.0, -2.0])
    base = (raw, *fit_ols(U[fit], d[fit]))
    mu, W = whitener(U[fit])
    meta = {"fit_rows": len(fit), "novelty": {"inputs": ["temp_a_c", "temp_b_c"], "mean": mu.tolist(),
                                              "whiten": W.tolist(), "range_distance": float(np.quantile(
                                                  mahalanobis(U[fit], mu, W), RANGE_QUANTILE))}}
    ch = ChannelFit("greybox", "tau=10800", own, 0.0, np.array([1.0, 8.0, -2.0]), 1.0, base=base,
                    shrink_scale=scale, novelty=feature_novelty(own, F[fit]))
    return DriftModel({"ch1": ch}, meta)


def test_a_filtered_state_outside_its_range_counts_though_every_raw_input_is_inside():
    log, fit = _slow_state_log()
    m = _slow_state_model(log, fit)
    late = np.arange(len(log.time_s) - 200, len(log.time_s))
    raw = m.rho(log)
    rho = m.channel_rho(log)["ch1"]
    assert np.median(raw[late]) <= 1.0                     # the raw inputs stay in their range ...
    assert np.median(rho[late]) > 2.0                      # ... the 3 h state does not
    assert np.all(rho >= raw)
    fixed = m.predict(log, distance_shrink=False)["ch1"]
    pred = m.predict(log)["ch1"]
    bf, ba, bc = m.channels["ch1"].base
    b = ba + feature_matrix(log, bf) @ bc
    inside = rho <= 1
    np.testing.assert_allclose(pred[inside], fixed[inside], atol=SAME_UM, rtol=0)
    out = (rho > 1) & (np.abs(fixed - b) > 0.1)
    g = (pred[out] - b[out]) / (fixed[out] - b[out])
    np.testing.assert_allclose(g, distance_weight(rho[out], 0.5), atol=RATIO_ATOL, rtol=0)
    np.testing.assert_allclose(m.band_um(log)["ch1"], 1.0 * np.maximum(1.0, rho), atol=SAME_UM, rtol=0)


def test_the_feature_distance_survives_the_json_form():
    log, fit = _slow_state_log()
    m = _slow_state_model(log, fit)
    obj = m.to_json()
    assert "feature_distance" in obj["channels"]["ch1"]
    back = DriftModel.from_json(obj)
    np.testing.assert_allclose(back.channel_rho(log)["ch1"], m.channel_rho(log)["ch1"], atol=JSON_ATOL_UM, rtol=0)
    np.testing.assert_allclose(back.predict(log)["ch1"], m.predict(log)["ch1"], atol=JSON_ATOL_UM, rtol=0)


def test_conformal_quantile_is_the_rank_that_covers_the_level():
    z = np.arange(1.0, 20.0)                               # 19 scores: ⌈20 · 0.95⌉ = 19 → the largest
    assert conformal_quantile(z, 0.95) == 19.0
    assert conformal_quantile(np.arange(1.0, 101.0), 0.95) == 96.0   # ⌈101 · 0.95⌉ = 96
    rng = np.random.default_rng(5)
    cover = []
    for _ in range(200):                                   # exchangeable scores: a new one is covered ≥ 95 %
        s = np.abs(rng.normal(size=41))
        cover.append(s[-1] <= conformal_quantile(s[:-1], 0.95))
    assert np.mean(cover) >= 0.95 - 3 * np.sqrt(0.95 * 0.05 / 200)   # 3 binomial σ below the level at most


def test_running_reference_equals_the_whitener_on_the_rows_seen():
    rng = np.random.default_rng(2)
    U = rng.normal(size=(500, 3)) * [1.0, 50.0, 0.1] + [20.0, 5000.0, 1.0]
    new = rng.normal(size=(40, 3)) * [2.0, 80.0, 0.3] + [23.0, 6000.0, 1.5]
    mu, W = whitener(U)
    ref = RunningReference(mu, W, len(U))
    probe = rng.normal(size=(30, 3)) * [3.0, 100.0, 0.5] + [21.0, 5500.0, 1.2]
    np.testing.assert_allclose(ref.distance(probe), mahalanobis(probe, mu, W), rtol=REFERENCE_RTOL)
    for u in new:
        ref.add(u)
    mu2, W2 = whitener(np.vstack([U, new]))
    np.testing.assert_allclose(ref.distance(probe), mahalanobis(probe, mu2, W2), rtol=REFERENCE_RTOL)


def _step_setup(seed=0, n=1500, n_fit=700):
    """The slow-state log and model; from row n_fit on the machine runs outside the state's range AND its first
    gain steps by a quarter with a +3 μm offset: measured every MEASURE_EVERY rows from n_fit on."""
    log, fit = _slow_state_log(seed, n, n_fit)
    m = _slow_state_model(log, fit)
    c = m.channels["ch1"]
    F = feature_matrix(log, c.features)
    truth = np.where(np.arange(n) < n_fit, F @ c.coef, 3.0 + F @ (c.coef * [1.25, 1.0, 1.0]))
    y = truth + np.random.default_rng(seed).normal(0, NOISE_UM, n)
    meas = np.full(n, np.nan)
    meas[n_fit::MEASURE_EVERY] = y[n_fit::MEASURE_EVERY]
    return log, m, truth, meas, n_fit


def test_update_without_measurements_is_the_saved_model_with_its_distance_rule():
    log, m, _, meas, _ = _step_setup()
    res = DriftUpdater(noise_um=NOISE_UM).run(m, log, {"ch1": np.full_like(meas, np.nan)})
    np.testing.assert_allclose(res.pred_um["ch1"], m.predict(log)["ch1"], atol=SAME_UM, rtol=0)
    np.testing.assert_allclose(res.band_um["ch1"], m.band_um(log)["ch1"], atol=SAME_UM, rtol=0)


def test_updated_distance_learns_the_new_regime_and_the_update_converges():
    log, m, truth, meas, n_fit = _step_setup()
    res = DriftUpdater(noise_um=NOISE_UM).run(m, log, {"ch1": meas})
    saved_rho = m.channel_rho(log)["ch1"]
    q = len(truth) * 3 // 4
    assert np.median(saved_rho[q:]) > 2.0                  # the saved model's distance: far outside, shrunk
    # measured there many times: the grown reference (one mean and covariance over the fit data and the ~160
    # measured rows) pulls the regime in — at least halfway; not all the way, a pooled reference is one ellipsoid
    assert np.median(res.rho["ch1"][q:]) < RHO_LEARNED * np.median(saved_rho[q:])
    assert np.all(res.rho["ch1"][:n_fit + 1] == saved_rho[:n_fit + 1])   # nothing seen yet: the same distance
    h = np.array(res.history["ch1"])
    late = h[-len(h) // 4:]
    assert np.sqrt(np.mean(late[:, 1] ** 2)) < CONVERGED_SIGMA * NOISE_UM
    assert np.sqrt(np.mean(late[:, 2] ** 2)) > STEP_SIGMA * NOISE_UM
    assert np.sqrt(np.mean((res.pred_um["ch1"][q:] - truth[q:]) ** 2)) < CONVERGED_SIGMA * NOISE_UM


def test_updated_prediction_up_to_a_row_ignores_later_samples():
    log, m, _, meas, n_fit = _step_setup()
    a = DriftUpdater(noise_um=NOISE_UM).run(m, log, {"ch1": meas})
    cut = n_fit + 20 * MEASURE_EVERY                       # a measured row in the new regime
    assert np.isfinite(meas[cut])
    changed = meas.copy()
    changed[cut:] += 40.0                                  # later measurements ...
    alt = DriftLog(log.time_s, {s: v.copy() for s, v in log.temps_c.items()}, {}, None, "<alt>")
    alt.temps_c["a"][cut + 1:] += 5.0                      # ... and later inputs change
    b = DriftUpdater(noise_um=NOISE_UM).run(m, alt, {"ch1": changed})
    np.testing.assert_allclose(b.pred_um["ch1"][:cut + 1], a.pred_um["ch1"][:cut + 1], atol=CAUSAL_ATOL_UM, rtol=0)
    np.testing.assert_allclose(b.band_um["ch1"][:cut + 1], a.band_um["ch1"][:cut + 1], atol=CAUSAL_ATOL_UM, rtol=0)
    assert np.abs(b.pred_um["ch1"][cut + 1:] - a.pred_um["ch1"][cut + 1:]).max() > 1.0


# -- the selection rule's settings ---------------------------------------------------------------------------------
def test_selection_settings_are_checked_before_fitting():
    from errormap.diagnosis.drift_models import DriftSelector
    log, _ = _slow_state_log()
    for kw in ({"shrink_weights": (1.5,)}, {"shrink_weights": ()}, {"band_rule": "gaussian"}):
        with pytest.raises(ValueError, match=next(iter(kw)).split("_")[0]):
            DriftSelector(**kw).fit(log)


def _eligible_keys(sel, ch):
    names = set(sel.eligible_[ch])
    out = []
    for k in sel.candidates_[ch]:
        f, hy, w = k
        if f"{f}{'[' + hy + ']' if hy else ''}" + ("" if w == 1.0 else f"~ols(w={w:g})") in names:
            out.append(k)
    return out


@pytest.mark.slow   # one selection on a 46 h log at 120 s (~6 CPU s)
def test_the_default_rule_chooses_the_eligible_candidate_of_largest_mean_gain():
    from errormap.diagnosis.drift_models import DriftSelector
    from drift_fixtures import drift_log_of
    from errormap.diagnosis.drift_sim import SIMULATORS
    log = drift_log_of(SIMULATORS["lumped"](0, dt_s=120.0, shift_at=0.6, n_dropouts=0))
    plain = DriftSelector(fit_fraction=0.6).fit(log)        # the default: largest mean gain
    picked = 0
    for ch, (pf, ph) in plain.chosen_.items():
        ok = _eligible_keys(plain, ch)
        if pf == "ols":
            assert not ok                                  # OLS only where no candidate passed every gate
            continue
        picked += 1
        k = (pf, ph, plain.shrink_[ch])
        assert plain.candidates_[ch][k]["gain"] == max(plain.candidates_[ch][j]["gain"] for j in ok)
    assert picked                                          # the rule was exercised on this log
    # the two band scales from the same fold residuals: the ρ-scaled scores |r| / max(1, ρ) are each ≤ |r|, so
    # their conformal quantile is ≤ the undivided one (the default), and both are positive
    for ch in plain.chosen_:
        alt, gamma_alt = plain.band_alt_[ch]["rho_scaled"]
        assert gamma_alt == 1.0 and 0 < alt <= plain.band_[ch][0]
        assert plain.model_.channels[ch].band95_um == plain.band_[ch][0]
