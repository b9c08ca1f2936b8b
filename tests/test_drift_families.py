"""The physically constrained drift families added in issue 29's third round (temperature differences,
temperature modes, a grey-box state on the modes, stably selected sensors through one lag each): each
recovers a drift of its own structure, and the constraint it is named for holds exactly."""
import numpy as np
import pytest

from drift_fixtures import simulate_drift_log
from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import (Feature, GradientFamily, GreyBoxModesFamily, ModesFamily, OLSFamily,
                                               StableLagOLSFamily, feature_matrix, first_order)

# the simulated displacement noise (N(0, 0.5 μm)); a family of the drift's own structure leaves about that, and
# 0.6 μm allows for its few fitted parameters (≤ 10 on 2160 rows) and the 0.01 °C sensor noise times gains
# of a few μm/°C
NOISE_UM = 0.5
RECOVERED_RMS_UM = 0.6
# exact constraints (a sum of gains, a reparametrisation of OLS): float precision on gains of ~10 μm/°C and
# predictions of ~100 μm
EXACT_ATOL = 1e-8


def _log(seed=0, n=2160, dt_s=60.0):
    """Six temperatures and the speed of the drift simulator (1.5 days at 60 s), no displacement yet."""
    cols = simulate_drift_log(seed, n=n, dt_s=dt_s, n_sensors=6, channels=())
    cols.pop("_truth")
    temps = {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")}
    return DriftLog(cols["time_s"], temps, {}, cols["speed_rpm"], "<sim>")


def _with(log, **disp_um):
    rng = np.random.default_rng(7)
    return DriftLog(log.time_s, log.temps_c, {k: v + rng.normal(0, NOISE_UM, len(v)) for k, v in disp_um.items()},
                    log.speed_rpm, log.path)


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def _predict(log, model):
    feats, a, b = model
    return a + feature_matrix(log, feats) @ np.asarray(b)


def test_gradient_sum0_ignores_a_uniform_temperature_shift_and_recovers_a_gradient():
    base = _log()
    T = base.temps_c
    coolest = min(T, key=lambda s: np.median(T[s]))
    other = next(s for s in T if s != coolest)
    log = _with(base, ch=5.0 * (T[other] - T[coolest]))
    rows = np.arange(len(log.time_s))
    res = GradientFamily().fit(log, ["ch"], rows, {})["ch"]
    assert set(res) == {"sum0", "stable"}
    feats, a, b = res["sum0"]
    temp_gain = sum(c for f, c in zip(feats, b) if f.input.startswith("temp_"))
    assert abs(temp_gain) < EXACT_ATOL                         # the gains on the temperatures sum to zero
    warmer = DriftLog(log.time_s, {s: v + 2.0 for s, v in T.items()}, log.disp_um, log.speed_rpm, log.path)
    np.testing.assert_allclose(_predict(warmer, res["sum0"]), _predict(log, res["sum0"]), atol=EXACT_ATOL, rtol=0)
    for hyper in ("sum0", "stable"):
        assert _rms(log.disp_um["ch"] - _predict(log, res[hyper])) < RECOVERED_RMS_UM, hyper


def test_modes_with_every_mode_is_ols_and_one_mode_recovers_a_one_mode_drift():
    base = _log(1)
    T = np.stack(list(base.temps_c.values()), axis=1)
    m1 = (T - T.mean(axis=0)) @ np.linalg.svd(T - T.mean(axis=0), full_matrices=False)[2][0]
    log = _with(base, ch=3.0 * m1, other=4.0 * (T[:, 1] - T[:, 4]))
    rows = np.arange(len(log.time_s))
    fam = ModesFamily(counts=(1, T.shape[1]))
    res = fam.fit(log, ["ch", "other"], rows, {})
    ols = OLSFamily().fit(log, ["ch", "other"], rows, {})
    for ch in ("ch", "other"):                   # every mode kept: a reparametrisation of the OLS baseline
        np.testing.assert_allclose(_predict(log, res[ch][f"k={T.shape[1]}"]), _predict(log, ols[ch][""]),
                                   atol=EXACT_ATOL, rtol=0)
    assert _rms(log.disp_um["ch"] - _predict(log, res["ch"]["k=1"])) < RECOVERED_RMS_UM


def test_greybox_modes_recovers_a_state_driven_by_the_first_mode():
    base = _log(2)
    T = np.stack(list(base.temps_c.values()), axis=1)
    m1 = (T - T.mean(axis=0)) @ np.linalg.svd(T - T.mean(axis=0), full_matrices=False)[2][0]
    slow = first_order(base.time_s, m1, 3600.0)
    log = _with(base, ch=2.0 * m1 + 6.0 * slow)
    fam = GreyBoxModesFamily()
    res = fam.fit(log, ["ch"], np.arange(len(log.time_s)), {})["ch"]
    assert sorted(res) == sorted(f"k={k};tau={t:g}" for k in fam.counts for t in fam.taus)
    feats, _, b = res["k=1;tau=3600"]
    assert len(feats) == len(b) == 2 * (T.shape[1] + 1)      # every raw input and its lag: the controller form
    assert _rms(log.disp_um["ch"] - _predict(log, res["k=1;tau=3600"])) < RECOVERED_RMS_UM
    # the wrong time constant leaves clearly more (the state's τ is identified by the data)
    assert _rms(log.disp_um["ch"] - _predict(log, res["k=1;tau=900"])) > 2 * RECOVERED_RMS_UM


def test_stable_lag_keeps_the_driving_sensor_at_its_time_constant():
    base = _log(3)
    s = sorted(base.temps_c)[2]
    log = _with(base, ch=4.0 * first_order(base.time_s, base.temps_c[s], 3600.0))
    res = StableLagOLSFamily().fit(log, ["ch"], np.arange(len(log.time_s)), {})["ch"]
    assert set(res) == {"k=3", "k=6"}
    for hyper, (feats, _, _) in res.items():
        assert Feature(f"temp_{s}_c", 3600.0) in feats, (hyper, [f.key for f in feats])
        assert len({f.input for f in feats}) == len(feats)     # one time constant per input
        assert _rms(log.disp_um["ch"] - _predict(log, res[hyper])) < RECOVERED_RMS_UM


@pytest.mark.parametrize("family", [GradientFamily, ModesFamily, GreyBoxModesFamily, StableLagOLSFamily])
def test_constrained_families_are_causal(family):
    """A prediction at row t uses the inputs up to t only: altering later samples leaves it unchanged."""
    base = _log(4, n=600)
    T = base.temps_c
    log = _with(base, ch=3.0 * first_order(base.time_s, T[sorted(T)[0]], 1800.0) - 2.0 * T[sorted(T)[3]])
    rows = np.arange(400)
    res = family().fit(log, ["ch"], rows, {})["ch"]
    cut = 300
    later = DriftLog(log.time_s, {k: np.r_[v[:cut], v[cut:] + 5.0] for k, v in T.items()}, log.disp_um,
                     np.r_[log.speed_rpm[:cut], log.speed_rpm[cut:] * 0.5], log.path)
    for hyper, model in res.items():
        np.testing.assert_allclose(_predict(later, model)[:cut], _predict(log, model)[:cut], atol=EXACT_ATOL, rtol=0)


def test_measured_families_are_not_defaults_and_run_in_a_selection():
    """The families are available to DriftSelector (``families=``) and the chosen model keeps the controller form:
    written to JSON and read back, it predicts what the selector's model predicts."""
    from errormap.diagnosis.drift_models import DriftModel, DriftSelector, default_families, measured_families
    names = {f.name for f in measured_families()}
    assert names == {"gradient", "modes", "greybox_modes", "ols_stable_lag"}
    assert not names & {f.name for f in default_families()}
    base = _log(5, n=1200)
    T = base.temps_c
    log = _with(base, ch=4.0 * (T[sorted(T)[1]] - T[sorted(T)[4]]) + 2.0 * first_order(base.time_s, T[sorted(T)[0]], 3600.0))
    sel = DriftSelector(fit_fraction=0.6, families=[OLSFamily()] + measured_families()).fit(log)
    assert set(sel.cv_["ch"]) >= {"gradient[sum0]", "modes[k=1]", "greybox_modes[k=1;tau=900]", "ols_stable_lag[k=3]"}
    back = DriftModel.from_json(sel.model_.to_json())
    np.testing.assert_allclose(back.predict(log)["ch"], sel.model_.predict(log)["ch"], atol=EXACT_ATOL, rtol=0)
