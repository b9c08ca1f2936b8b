"""The disagreement gate (issue 29, sixth round; a setting, ``DriftSelector(disagreement=…)``): where the chosen model
and its OLS baseline disagree on a sample by more than they did on the validation folds, the prediction is held at
that limit from OLS; inside it the model is unchanged. Causal, carried by save / load, ``--update`` and the export; a
file without it reads as before."""
import json

import numpy as np
import pytest

from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import (DISAGREEMENTS, ChannelFit, DriftModel, DriftSelector, Feature,
                                             disagreement_clip, disagreement_interval, feature_matrix)
from errormap.diagnosis.drift_update import DriftUpdater
from errormap.io import InputError
from tests.test_drift_distance import _log as _distance_log

# inside the interval the gated prediction IS the model's (the clip returns base + (pred − base): one float round trip
# on values of order 10 μm)
SAME_UM = 1e-12
# JSON stores floats with repr precision: the reloaded model reproduces predictions to round-off
JSON_ATOL_UM = 1e-9
CAUSAL_ATOL_UM = 1e-9       # predictions up to t must not move when later samples change (floating point only)
N_IN = 600                  # rows of the constructed log inside the range (its fitting part)
FAR_C = 4.0                 # temperature a leaves its range by this much over the last rows; b stays
GAIN_UM_PER_C = 2.0         # the candidate's extra gain on (a − b): zero-mean inside, FAR_C·2 μm away from OLS outside
FAR_SHARE = 0.8             # the last 50 of the 300 ramp rows are ≥ 250/300 of the way out (0.83), noise aside


def _log(n=900):
    """a and b move together (a − b: 0.02 °C noise) on the first N_IN rows; after it a ramps FAR_C out, b stays."""
    rng = np.random.default_rng(0)
    t = np.arange(n) * 60.0
    b = 22 + np.sin(t / 7000.0)
    a = b - 2.0 + 0.02 * rng.normal(size=n) + FAR_C * np.clip((np.arange(n) - N_IN) / (n - N_IN), 0, 1)
    sp = 5000 + 2000 * np.sin(t / 3000.0)
    d = 3 * (a - 20) - 2 * (b - 22) + 1e-3 * (sp - 5000)
    return DriftLog(t, {"a": a, "b": b}, {"ch1": d}, sp, "<test>")


def _model(log, gate=True):
    """OLS-like base and a candidate = base + GAIN·(a − b + 2): the two agree inside (a − b ≈ −2), not outside.
    The interval is the one :func:`disagreement_interval` gives on the first N_IN rows' differences."""
    base = ([Feature("temp_a_c"), Feature("temp_b_c"), Feature("speed_rpm")], -10.0, np.array([2.5, -1.5, 1e-3]))
    feats = [Feature("temp_a_c"), Feature("temp_b_c"), Feature("speed_rpm")]
    coef = base[2] + np.array([GAIN_UM_PER_C, -GAIN_UM_PER_C, 0.0])
    cand = ChannelFit("test", "", feats, base[1] + 2 * GAIN_UM_PER_C, coef, 1.5, base=base)
    m = DriftModel({"ch1": cand}, {})
    if gate:
        d = m.predict(log, distance_shrink=False)["ch1"] - (base[1] + feature_matrix(log, base[0]) @ base[2])
        cand.disagreement_um = disagreement_interval(d[:N_IN], "abs", 1.0)
    return m


def _base(log, model):
    bf, ba, bc = model.channels["ch1"].base
    return ba + feature_matrix(log, bf) @ bc


def test_interval_from_the_fold_differences():
    d = np.array([-0.5, 0.2, 1.0, -3.0, 0.1])
    assert disagreement_interval(d, "abs", 1.0) == (-3.0, 3.0)           # "more than they ever did": the largest |Δ|
    lo, hi = disagreement_interval(d, "abs", 0.5)
    assert hi == pytest.approx(np.quantile(np.abs(d), 0.5)) and lo == -hi
    # signed: a model that only ever moved the level up may not move it down (the interval still holds 0)
    assert disagreement_interval(np.array([0.5, 1.0, 2.0]), "signed", 1.0) == (0.0, 2.0)
    assert disagreement_interval(np.zeros(0), "abs") == (0.0, 0.0)       # no fold rows: the baseline
    for bad in ({"mode": "both"}, {"mode": "abs", "quantile": 0.0}, {"mode": "abs", "quantile": 1.5}):
        with pytest.raises(ValueError):
            disagreement_interval(d, bad["mode"], bad.get("quantile", 1.0))
    np.testing.assert_array_equal(disagreement_clip([5.0, -5.0, 0.5], [1.0, 1.0, 1.0], -1.0, 2.0), [3.0, 0.0, 0.5])


def test_equal_inside_the_range_and_held_at_the_fold_limit_outside():
    log = _log()
    model = _model(log)
    fixed = model.predict(log, distance_shrink=False)["ch1"]     # the fixed linear model: neither per-sample rule
    pred = model.predict(log)["ch1"]
    base = _base(log, model)
    lo, hi = model.channels["ch1"].disagreement_um
    assert 0 < hi < 0.2 and lo == -hi                            # the candidate barely disagrees with OLS inside
    np.testing.assert_allclose(pred[:N_IN], fixed[:N_IN], rtol=0, atol=SAME_UM)   # inside: unchanged
    # outside the two diverge by up to GAIN·FAR_C μm; the gated prediction stays within hi of OLS
    far = np.arange(len(pred)) >= len(pred) - 50
    assert np.all(np.abs(fixed[far] - base[far]) > FAR_SHARE * GAIN_UM_PER_C * FAR_C)
    assert np.all(np.abs(pred - base) <= hi + SAME_UM)
    np.testing.assert_allclose(pred[far], base[far] + hi, rtol=0, atol=SAME_UM)  # held at the limit, toward OLS
    assert np.abs(pred[far] - base[far]).max() < np.abs(fixed[far] - base[far]).min() / 30


def test_predictions_up_to_t_ignore_later_samples():
    log = _log()
    model = _model(log)
    before = model.predict(log)["ch1"]
    cut = 700
    late = np.arange(len(log.time_s)) > cut
    altered = DriftLog(log.time_s, {s: np.where(late, v + 5.0, v) for s, v in log.temps_c.items()}, log.disp_um,
                       np.where(late, 12000.0, log.speed_rpm), "<altered>")
    after = model.predict(altered)["ch1"]
    np.testing.assert_allclose(after[:cut + 1], before[:cut + 1], rtol=0, atol=CAUSAL_ATOL_UM)
    assert np.abs(after[cut + 1:] - before[cut + 1:]).max() > 1e-3


def test_json_round_trip_keeps_the_gate_and_an_old_file_reads_as_before(tmp_path):
    log = _log()
    model = _model(log)
    model.save(tmp_path / "m.json")
    obj = json.loads((tmp_path / "m.json").read_text())
    assert "distance_shrink" not in obj["channels"]["ch1"]      # the gate carries its own baseline
    back = DriftModel.load(tmp_path / "m.json")
    assert back.channels["ch1"].disagreement_um == model.channels["ch1"].disagreement_um
    np.testing.assert_allclose(back.predict(log)["ch1"], model.predict(log)["ch1"], rtol=0, atol=JSON_ATOL_UM)
    # a drift_model.json written before the gate existed: no key, the fixed model as before
    del obj["channels"]["ch1"]["disagreement_gate"]
    (tmp_path / "old.json").write_text(json.dumps(obj))
    old = DriftModel.load(tmp_path / "old.json")
    assert old.channels["ch1"].disagreement_um is None and old.channels["ch1"].base is None
    np.testing.assert_allclose(old.predict(log)["ch1"], model.predict(log, distance_shrink=False)["ch1"], rtol=0,
                               atol=JSON_ATOL_UM)
    # an interval that excludes the baseline itself is refused, naming the file and the channel
    obj = json.loads((tmp_path / "m.json").read_text())
    obj["channels"]["ch1"]["disagreement_gate"]["lo_um"] = 0.5
    (tmp_path / "bad.json").write_text(json.dumps(obj))
    with pytest.raises(InputError, match=r"bad\.json: key 'channels\.ch1'"):
        DriftModel.load(tmp_path / "bad.json")


def test_update_keeps_the_gate_on_the_updated_pair():
    log = _log()
    model = _model(log)
    saved = model.predict(log)["ch1"]
    none = DriftUpdater(noise_um=0.3).run(model, log, {"ch1": np.full(len(saved), np.nan)})
    np.testing.assert_allclose(none.pred_um["ch1"], saved, rtol=0, atol=SAME_UM)
    meas = np.full(len(saved), np.nan)
    meas[:N_IN:5] = log.disp_um["ch1"][:N_IN:5] + 1.0           # an offset the update learns
    res = DriftUpdater(noise_um=0.3).run(model, log, {"ch1": meas})
    up = res.model.channels["ch1"]
    assert up.disagreement_um == model.channels["ch1"].disagreement_um
    ubase = _base(log, res.model)                                # the updated baseline, saved with the model
    assert np.all(np.abs(res.pred_um["ch1"][N_IN:] - ubase[N_IN:]) <= up.disagreement_um[1] + 1e-9)


def test_selector_gate_is_the_returned_model_with_the_interval_and_checks_its_settings():
    with pytest.raises(ValueError, match="disagreement"):
        DriftSelector(disagreement="median").fit(_distance_log())
    assert DISAGREEMENTS[0] is None                              # off by default
    log = _distance_log()
    kw = dict(fit_fraction=0.6, n_novelty_folds=2, n_novelty_blocks=6)
    plain = DriftSelector(**kw).fit(log)
    gated = DriftSelector(disagreement="abs", **kw).fit(log)
    assert gated.chosen_ == plain.chosen_ and gated.shrink_ == plain.shrink_      # the selection is unchanged
    for ch, c in gated.model_.channels.items():
        if gated.chosen_[ch][0] == "ols":
            assert c.disagreement_um is None
            continue
        d = gated.fold_delta_[ch]
        assert c.disagreement_um == (-float(np.abs(d).max()), float(np.abs(d).max()))
        np.testing.assert_array_equal(c.coef, plain.model_.channels[ch].coef)
    assert gated.model_.meta["disagreement_gate"] == {"mode": "abs", "quantile": 1.0}
    assert "disagreement_gate" not in plain.model_.meta


def test_export_carries_the_gate(tmp_path):
    from compensation.app.cli import main
    from errormap.io import write_csv
    log = _log()
    _model(log).save(tmp_path / "m.json")
    write_csv(tmp_path / "log.csv", {"time_s": log.time_s, "temp_a_c": log.temps_c["a"],
                                     "temp_b_c": log.temps_c["b"], "speed_rpm": log.speed_rpm,
                                     "ch1_um": log.disp_um["ch1"]})
    assert main(["export", str(tmp_path / "m.json"), "--format", "drift", "--out", str(tmp_path / "exp"),
                 "--log", str(tmp_path / "log.csv")]) == 0
    ctl = json.loads((tmp_path / "exp" / "export.json").read_text())["controller"]
    rule = ctl["disagreement_gate"]["channels"]["ch1"]
    model = _model(log)
    assert (rule["lo_um"], rule["hi_um"]) == model.channels["ch1"].disagreement_um
    assert rule["base_gains"][-1] == -10.0                      # the offset row carries the baseline's intercept
    _model(log, gate=False).save(tmp_path / "p.json")
    assert main(["export", str(tmp_path / "p.json"), "--format", "drift", "--out", str(tmp_path / "exp2"),
                 "--log", str(tmp_path / "log.csv")]) == 0
    assert json.loads((tmp_path / "exp2" / "export.json").read_text())["controller"]["disagreement_gate"] is None
