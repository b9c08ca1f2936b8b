"""The drift selection's ranking rules and the ρ-power band (issue 29): numbers checked by hand, the band's γ
recovered from residuals that grow with a known power of ρ, the model file carrying γ (and files without it)."""
import json

import numpy as np
import pytest
from scipy.stats import t as student_t

from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import (BAND_GAMMAS, BAND_QUANTILE, ChannelFit, DriftModel, Feature, band_of,
                                             rho_power_band)
from errormap.io import InputError
from errormap.seeds import spawn_rngs

EXACT = 1e-12        # closed-form scores: floating point only
# the conformal quantile of n exchangeable scores covers at least the level, and at most level + 1/n of them
COVER_SLACK = 1e-9
OUT_COVER_SE = 1.0   # the band's own tolerance (drift_models.BAND_SUBSET_SE): one binomial SE on a subset
GAMMA_STEP = 0.5     # the spacing of BAND_GAMMAS below 3


def _stats(h, n, rho_h=None, rho_n=None, gain=0.1):
    return {"gain": gain, "fold_ratios": ([0.9, 0.9], list(h), list(n)),
            "fold_rho_each": ([1.0, 1.0], list(rho_h or [1.0] * len(h)), list(rho_n or [1.0] * len(n)))}


@pytest.mark.parametrize("power", [0.0, 1.0, 2.0])
def test_rho_power_band_recovers_the_growth_of_the_fold_errors(power):
    rng = spawn_rngs(29, 2)[0]
    rho = np.concatenate([rng.uniform(0.2, 1.0, 2000), rng.uniform(1.0, 4.0, 2000)])
    r = np.abs(rng.normal(0.0, 1.0, rho.size)) * np.maximum(1.0, rho) ** power
    q, g = rho_power_band(r, rho)
    assert g in BAND_GAMMAS
    grow = np.maximum(1.0, rho) ** g
    cover = np.mean(r <= q * grow)
    assert BAND_QUANTILE - COVER_SLACK <= cover <= BAND_QUANTILE + 1.0 / rho.size + COVER_SLACK
    out = rho > 1
    assert np.mean(r[out] <= q * grow[out]) >= BAND_QUANTILE - OUT_COVER_SE * np.sqrt(
        BAND_QUANTILE * (1 - BAND_QUANTILE) / out.sum())
    # the smallest γ of the grid that covers the out-of-range rows: the true power within one grid step
    # (a subset's coverage is a sample: a neighbouring γ may pass or fail by its binomial scatter)
    assert abs(g - power) <= GAMMA_STEP


def test_rho_power_band_without_out_of_range_rows_grows_like_the_default():
    rng = spawn_rngs(29, 2)[1]
    r, rho = np.abs(rng.normal(0, 1, 500)), rng.uniform(0, 1, 500)
    q, g = rho_power_band(r, rho)
    assert g == 1.0 and q == pytest.approx(np.sort(r)[int(np.ceil(501 * BAND_QUANTILE)) - 1], abs=EXACT)
    st = {"band_rho_power": (2.0, 1.5), "band_fold_residual": 3.0, "band_rho_scaled": 1.0}
    assert band_of(st, "rho_power") == (2.0, 1.5) and band_of(st, "fold_residual") == (3.0, 1.0)


def _model(gamma):
    t = np.arange(0.0, 7200.0, 60.0)
    log = DriftLog(t, {"a": 20 + t / 3600.0}, {"z": np.zeros(t.size)}, None)
    meta = {"novelty": {"inputs": ["temp_a_c"], "mean": [20.5], "whiten": [[2.0]], "range_distance": 1.0}}
    c = ChannelFit("ols", "", [Feature("temp_a_c")], 0.0, np.array([1.0]), 2.0, band_gamma=gamma)
    return DriftModel({"z": c}, meta), log


def test_band_grows_with_the_models_gamma_and_round_trips(tmp_path):
    m, log = _model(2.0)
    rho = m.channel_rho(log)["z"]
    assert rho.max() > 1.5          # the log leaves the range: the growth is exercised
    np.testing.assert_allclose(m.band_um(log)["z"], 2.0 * np.maximum(1.0, rho) ** 2, rtol=0, atol=EXACT)
    m.save(tmp_path / "m.json")
    obj = json.loads((tmp_path / "m.json").read_text())
    assert obj["channels"]["z"]["band_gamma"] == 2.0 and "** band_gamma" in obj["channels"]["z"]["band_rule"]
    back = DriftModel.load(tmp_path / "m.json")
    np.testing.assert_allclose(back.band_um(log)["z"], m.band_um(log)["z"], rtol=0, atol=EXACT)
    # a file written before the ρ-power band has no band_gamma: γ = 1, the band it was written with
    del obj["channels"]["z"]["band_gamma"]
    (tmp_path / "old.json").write_text(json.dumps(obj))
    np.testing.assert_allclose(DriftModel.load(tmp_path / "old.json").band_um(log)["z"],
                               2.0 * np.maximum(1.0, rho), rtol=0, atol=EXACT)
    obj["channels"]["z"]["band_gamma"] = -1
    (tmp_path / "bad.json").write_text(json.dumps(obj))
    with pytest.raises(InputError, match="channels.z"):
        DriftModel.load(tmp_path / "bad.json")


@pytest.mark.slow   # two selections on a 46 h log at 120 s (~12 CPU s)
def test_rho_power_band_in_a_fitted_model():
    from errormap.diagnosis.drift_models import DriftSelector
    from drift_fixtures import drift_log_of
    from errormap.diagnosis.drift_sim import SIMULATORS
    log = drift_log_of(SIMULATORS["lumped"](0, dt_s=120.0, shift_at=0.6, n_dropouts=0))
    sel = DriftSelector(fit_fraction=0.6, band_rule="rho_power").fit(log)
    plain = DriftSelector(fit_fraction=0.6).fit(log)        # the default band
    rep = sel.report(log)
    for ch, (f, hy) in sel.chosen_.items():
        # the band rule does not take part in the selection
        assert sel.eligible_[ch] == plain.eligible_[ch] and (f, hy) == plain.chosen_[ch]
        # the model carries the chosen candidate's (q, γ); the report gives every band rule on the same rows
        c = sel.model_.channels[ch]
        assert (c.band95_um, c.band_gamma) == sel.band_[ch] and c.band_gamma in BAND_GAMMAS
        assert set(rep[ch]["bands_heldout"]) == {"fold_residual", "rho_scaled", "rho_power", "fold_flat"}
        assert rep[ch]["bands_heldout"]["rho_power"]["coverage"] == rep[ch]["band_coverage_heldout"]
        # the flat band is the default band's scale without growth: never wider, held out
        fr, ff = (rep[ch]["bands_heldout"][b]["halfwidth_median_um"] for b in ("fold_residual", "fold_flat"))
        assert ff <= fr
