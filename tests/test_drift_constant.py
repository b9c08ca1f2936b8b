"""The constant offset beside OLS: a candidate judged by the same validation, and the plainest-baseline rule (never
ship a model that loses to OLS or to the constant in validation); ``deploy`` refits the choice on every row.

Simulated logs with a known truth: where the displacement is an offset plus slow noise that the temperatures do not
explain, the constant must win; where it is a linear function of the temperatures as logged, OLS must win."""

import json

import numpy as np
import pytest

from compensation.app.workflows.drift import run_drift
from errormap.diagnosis.drift import DriftLog, load_drift_log
from errormap.diagnosis.drift_models import (ConstantFamily, DriftSelector, OLSFamily, candidate_name, constant_gate,
                                            default_families)
from errormap.io import write_csv

DT_S, N_ROWS = 120.0, 900           # 30 h at 2 min
OFFSET_UM = 7.0
# the truth's own noise (μm, white); in the OLS case it is the floor both baselines are judged against
NOISE_UM = 0.3
# a constant is exactly the mean of the rows it is fitted on: floating point only
MEAN_RTOL = 1e-12
# OLS case: the constant misses the temperature-driven part (several μm) by far more than this factor
CONSTANT_LOSES_BY = 3.0


def _walk(rng, n, step):
    return np.cumsum(rng.normal(0.0, step, n))


def _log(seed: int, linear: bool) -> DriftLog:
    """Three temperatures that wander (random walks, °C) and one channel ``ch``: ``linear`` → 2·a − 1.5·b + noise
    (OLS's own model); else OFFSET_UM + a slow 0.3 μm swing + noise the temperatures do not drive
    (any gain OLS gives the wandering temperatures is spurious)."""
    rng = np.random.default_rng(seed)
    t = np.arange(N_ROWS) * DT_S
    temps = {s: 20.0 + _walk(rng, N_ROWS, 0.05) for s in ("a", "b", "c")}
    if linear:
        d = 2.0 * (temps["a"] - 20.0) - 1.5 * (temps["b"] - 20.0) + rng.normal(0.0, NOISE_UM, N_ROWS)
    else:
        d = OFFSET_UM + 0.3 * np.sin(t / 7200.0) + rng.normal(0.0, NOISE_UM, N_ROWS)
    return DriftLog(t, temps, {"ch": d}, None, f"<sim {seed}>")


def _selector(**kw):
    return DriftSelector(fit_fraction=0.6, families=[OLSFamily(), ConstantFamily()], **kw)


def test_the_constant_is_a_default_candidate_fitted_as_the_mean():
    assert "constant" in {f.name for f in default_families()}
    log = _log(0, linear=False)
    rows = np.arange(100, 400)
    feats, a, b = ConstantFamily().fit(log, ["ch"], rows, {})["ch"][""]
    assert feats == [] and b.shape == (0,)
    assert a == pytest.approx(np.mean(log.disp_um["ch"][rows]), rel=MEAN_RTOL)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_constant_wins_where_the_drift_is_an_offset(seed):
    log = _log(seed, linear=False)
    sel = _selector().fit(log)
    rep = sel.report(log)["ch"]
    assert sel.chosen_["ch"] == ("constant", "")
    # chosen by the validation: its mean log-gain over OLS is above 0, and no eligible model beat it
    assert sel.gain_["ch"][rep["model"]] > 0
    assert all(sel.gain_["ch"][k] > sel.gain_["ch"]["constant"] for k in sel.eligible_["ch"] if k != "constant")
    # and held out (the last 40 %), judged against the measured displacement: not worse than OLS
    assert rep["rms_after_um"] <= rep["rms_ols_um"]
    fit, _ = sel.split(log)
    assert sel.model_.channels["ch"].intercept_um == pytest.approx(np.mean(log.disp_um["ch"][fit]), rel=MEAN_RTOL)


@pytest.mark.parametrize("seed", [0, 1])
def test_ols_wins_where_the_drift_is_linear_in_the_temperatures(seed):
    log = _log(seed, linear=True)
    sel = _selector().fit(log)
    rep = sel.report(log)["ch"]
    assert sel.chosen_["ch"] == ("ols", "")
    assert sel.gain_["ch"]["constant"] < 0 and "constant" not in sel.eligible_["ch"]
    assert rep["rms_after_um"] == rep["rms_ols_um"]
    assert rep["rms_constant_um"] > CONSTANT_LOSES_BY * rep["rms_ols_um"]


def test_deploy_refits_the_chosen_constant_on_every_row_and_the_output_records_both(tmp_path):
    log = _log(0, linear=False)
    n = len(log.time_s)
    cols = {"time_s": log.time_s, **{f"temp_{s}_c": v for s, v in log.temps_c.items()}, "ch_um": log.disp_um["ch"]}
    write_csv(tmp_path / "log.csv", cols)
    sel = _selector(deploy=True)
    summary, _ = run_drift(tmp_path / "log.csv", tmp_path / "out", sel)
    log = load_drift_log(tmp_path / "log.csv")           # the figures as written (the CSV's precision)
    fit, _ = sel.split(log)
    assert sel.chosen_["ch"] == ("constant", "")
    # validated on the split, deployed on every row
    assert sel.model_.channels["ch"].intercept_um == pytest.approx(np.mean(log.disp_um["ch"][fit]), rel=MEAN_RTOL)
    assert sel.deployed_.channels["ch"].intercept_um == pytest.approx(np.mean(log.disp_um["ch"]), rel=MEAN_RTOL)
    dep = summary["deployed"]
    assert dep["rows_used"] == n == dep["rows_in_log"] and dep["validated_on_rows"] == len(fit)
    assert dep["channels"]["ch"]["candidate"] == summary["channels"]["ch"]["model"] == "constant"
    # the validation figures with both plain baselines beside, and the shipped file is the deployed fit
    c = summary["channels"]["ch"]
    assert {"rms_after_um", "rms_ols_um", "rms_constant_um", "cv_rms_constant_um"} <= set(c)
    shipped = json.loads((tmp_path / "out" / "drift_model.json").read_text())
    assert shipped["fitted_on"]["fit_rows"] == n
    assert shipped["channels"]["ch"]["intercept_um"] == pytest.approx(np.mean(log.disp_um["ch"]), rel=MEAN_RTOL)


# the offset-only log of seed 0: with every default family, ridge_ols[lambda=0.001]~ols(w=0.75) passed every gate
# against OLS and scored above the constant (the plain fallback there: its mean log-gain over OLS 0.165) on average,
# but beat it on the folds by t = 1.68 only (below the one-sided 95 % t quantile, 1.81 for 11 folds); shipped, it left
# 0.572 μm held out against the constant's 0.367 (docs/decisions/021)
REFUSED_ON_SEED_0 = "ridge_ols[lambda=0.001]~ols(w=0.75)"


def test_a_model_the_constant_matches_on_the_folds_is_refused_and_the_constant_ships():
    log = _log(0, linear=False)
    sel = DriftSelector(fit_fraction=0.6).fit(log)
    rep = sel.report(log)["ch"]
    assert sel.chosen_["ch"] == ("constant", "")
    assert REFUSED_ON_SEED_0 in rep["refused_by_constant"]
    # every refused model passed every gate against OLS: the constant test alone refused it
    cands = sel.candidates_["ch"]
    const = cands[("constant", "", 1.0)]
    for k, st in cands.items():
        name = candidate_name(*k)
        passed_ols = k[0] not in ("ols", "constant") and sel.eligible(st, st["gate"], k[2], cands[("ols", "", 1.0)]
                                                                        ["ranking"], True) and st["gain"] > const["gain"]
        assert (name in rep["refused_by_constant"]) == (passed_ols and const["gain"] > 0 and not constant_gate(st, const)[0])
    # held out (the last 40 %), against the measured displacement: the constant's figure, below OLS's
    assert rep["rms_after_um"] == rep["rms_constant_um"] < rep["rms_ols_um"]
    assert "paired one-sided t-test" in sel.model_.meta["selection"]


def test_the_constant_test_is_a_paired_one_sided_t_test_over_every_fold():
    # fold ratios to OLS: (ranking, horizon, novelty) folds; d_i = ln(constant_i / candidate_i)
    const = {"fold_ratios": ([1.0, 1.0], [1.0, 1.0], [1.0])}
    steady = {"fold_ratios": ([0.9, 0.9], [0.8, 0.8], [0.9])}     # better on every fold
    mixed = {"fold_ratios": ([0.5, 1.6], [0.6, 1.5], [0.9])}      # better on average, worse on two folds
    ok, mean, se = constant_gate(steady, const)
    d = -np.log([0.9, 0.9, 0.8, 0.8, 0.9])
    assert ok and mean == pytest.approx(d.mean(), rel=MEAN_RTOL)
    assert se == pytest.approx(d.std(ddof=1) / np.sqrt(5), rel=MEAN_RTOL)
    assert not constant_gate(mixed, const)[0]
    assert not constant_gate(const, const)[0]         # no gain: never a pass
