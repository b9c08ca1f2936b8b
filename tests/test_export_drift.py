"""`volcomp export --format drift`: the drift model as controller coefficients, checked from the file alone."""
import json

import numpy as np
import pytest

from compensation import export as ex
from compensation.app.cli import main
from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import ChannelFit, DriftModel, DriftSelector, Feature
from errormap.diagnosis.drift_sim import simulate_lumped_log
from errormap.io import InputError, read_table, write_csv

# a hand-computed value through exp(): float64 arithmetic, a handful of operations on values ~40 μm
HAND_UM = 1e-9
# the controller at the log's own sampling step runs the model's own recursion from the file's
# 15 significant digits: gains ~10 μm/°C on ~30 °C, ~80 terms → ≤ 1e-11 μm measured; 1e-8 leaves
# room for the summation order and is still 8 orders below any thermal figure
ROUND_TRIP_UM = 1e-8
# the controller at dt = step/k on held inputs equals the model on the log resampled (held) at dt:
# the same recursion, different float order; 1e-8 μm as above
RESAMPLED_UM = 1e-8
# a drift model's prediction moves by a μm over a log step on this log (measured 1.4 μm at 1 s,
# 3.4 μm at 120 s): 1e-6 μm cannot be met off the log's step
IMPOSSIBLE_UM = 1e-6


def one_filter_model(tau_s=100.0, delay_s=15.0, coef=2.0, intercept_um=1.0):
    f = Feature("temp_s1_c", tau_s, delay_s)
    return DriftModel({"ch1": ChannelFit("hand", "", [f], intercept_um, np.array([coef]))})


def step_log(n=40, dt=10.0, before=20.0, after=30.0):
    t = np.arange(n) * dt
    temp = np.where(t >= 10.0, after, before)
    return DriftLog(t, {"s1": temp}, {"ch1": np.zeros(n)}, None, "<step>")


def _frame(cols, path="<sim>"):
    return DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                    {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols["speed_rpm"], path)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A model fitted by the user's path (DriftSelector) on a 16 h simulated log sampled every 60 s (the tests
    that use it are in the slow tier: the fit takes 5–6.5 CPU s; on a 12 h log every channel comes back OLS,
    with no filter for the controller to run)."""
    cols = simulate_lumped_log(0, hours=16.0, dt_s=60.0, n_dropouts=0)
    cols.pop("_truth")
    log = _frame(cols)
    model = DriftSelector(fit_fraction=0.6).fit(log).model_
    d = tmp_path_factory.mktemp("fitted")
    model.save(d / "m.json")
    write_csv(d / "log.csv", cols)
    return model, log, d


def test_hand_value_of_a_one_filter_model(tmp_path):
    """ch1 = 1 + 2·lag(temp, τ = 100 s) delayed 15 s, at dt = 10 s: a = e^-0.1, b = 1 − a, the delay
    is 1.5 samples. Temperature steps 20 → 30 °C at t = 10 s: y0 = 20, y1 = 20 + 10b; at t = 20 s the
    feature is y(5 s) = (y0 + y1)/2 = 20 + 5b, so the prediction is 41 + 10b = 41.9516258196 μm."""
    coef = ex.drift_coefficients(one_filter_model(), 10.0)
    p = ex.write_drift_coefficients(coef, tmp_path, "hand")
    back = ex.read_drift_coefficients(p)
    a = np.exp(-0.1)
    assert back.sample_period_s == 10.0
    assert back.inputs == ["temp_s1_c", "const"]
    assert back.a[0] == pytest.approx(a, abs=1e-15) and back.b[0] == pytest.approx(1 - a, abs=1e-15)
    assert (back.a[1], back.b[1]) == (0.0, 1.0)
    assert list(back.delay_samples) == [1, 0] and back.delay_frac[0] == pytest.approx(0.5)
    assert list(back.gains["ch1"]) == [2.0, 1.0]
    log = step_log()
    hand = 41.0 + 10.0 * (1.0 - a)
    ticks, pred = ex.controller_drift(back, log.time_s, {"temp_s1_c": log.temps_c["s1"]})
    assert ticks[2] == 20.0
    assert pred["ch1"][2] == pytest.approx(hand, abs=HAND_UM)
    assert pred["ch1"][0] == pytest.approx(41.0, abs=HAND_UM)          # at rest: 1 + 2·20
    assert one_filter_model().predict(log)["ch1"][2] == pytest.approx(hand, abs=HAND_UM)
    head = read_table(p).comments   # its provenance sidecar
    assert "format: volcomp-drift-coefficients/1" in head and "sample_period_s: 10" in head
    assert any("y_r = a_r * y_r + b_r * v_r" in h for h in head)


@pytest.mark.slow  # uses the fitted fixture (a whole selection, > 5 CPU s)
def test_round_trip_at_the_log_step_reproduces_the_model(fitted, tmp_path):
    """export → file → read back → the controller's recursion at the log's sampling step (60 s)
    reproduces DriftModel.predict on every channel and sample: the stated discretisation error at
    the model's own step is zero but for float rounding."""
    model, log, _ = fitted
    res = ex.export_drift_coefficients(model, tmp_path, 60.0, log, "test", tolerance_um=ROUND_TRIP_UM)
    assert res["tolerance_met"]
    for ch, r in res["check"].items():
        assert r["model"]["max_um"] <= ROUND_TRIP_UM, ch
        assert r["model"]["n"] == len(log.time_s)
        # compensation from the coefficients is the model's own compensation, measured against the log
        assert r["measured"]["controller"]["rms_um"] == pytest.approx(r["measured"]["volcomp"]["rms_um"], abs=1e-6)
    # the library refuses too (the CLI discards its staging folder on this error)
    with pytest.raises(ValueError, match="tolerance not met"):
        ex.export_drift_coefficients(model, tmp_path, 120.0, log, "test", tolerance_um=IMPOSSIBLE_UM)


@pytest.mark.slow  # uses the fitted fixture (a whole selection, > 5 CPU s)
def test_sub_step_controller_equals_the_model_on_the_held_resampled_log(fitted):
    """At dt = step/4 the controller sees each logged value held until the next: exactly the model run
    on the log resampled every 15 s with held values, read at the original times (an independent path
    through volcomp's own feature code). What differs from the model on the 60 s log is the model's
    convention that a logged value acts over the interval before it, reported as the model residual."""
    model, log, _ = fitted
    coef = ex.drift_coefficients(model, 15.0)
    ctrl = ex.controller_drift_at(coef, log)
    t = np.arange(0.0, log.time_s[-1] + 1e-9, 15.0)
    j = np.searchsorted(log.time_s, t, side="right") - 1
    fine = DriftLog(t, {s: v[j] for s, v in log.temps_c.items()}, {}, log.speed_rpm[j], "<held>")
    ref = model.predict(fine, distance_shrink=False)    # the gains are the model without the distance rule
    at = np.searchsorted(t, log.time_s)
    for ch in model.channels:
        np.testing.assert_allclose(ctrl[ch], ref[ch][at], rtol=0, atol=RESAMPLED_UM)
    check = ex.check_drift_export(coef, model, log)
    assert ex.worst_drift_model_um(check) > 100 * RESAMPLED_UM    # the convention's cost is reported, not hidden


def test_irregular_log_ticks_at_the_fixed_period_on_held_inputs():
    """An unevenly sampled log (steps 3–17 s, whole seconds): the controller at dt = 1 s ticks on
    every whole second and holds each logged value until the next, so at every log time it equals
    the model run on that held 1 s staircase (the documented rule for irregular samples)."""
    rng = np.random.default_rng(7)
    t = np.concatenate([[0.0], np.cumsum(rng.integers(3, 18, 300)).astype(float)])
    temp = 20.0 + np.cumsum(rng.normal(0, 0.05, t.size))
    log = DriftLog(t, {"s1": temp}, {}, None, "<irregular>")
    model = one_filter_model(tau_s=120.0, delay_s=7.0, coef=4.0, intercept_um=-80.0)
    ctrl = ex.controller_drift_at(ex.drift_coefficients(model, 1.0), log)["ch1"]
    fine_t = np.arange(0.0, t[-1] + 1.0)
    held = temp[np.searchsorted(t, fine_t, side="right") - 1]
    ref = model.predict(DriftLog(fine_t, {"s1": held}, {}, None, "<held>"))["ch1"]
    np.testing.assert_allclose(ctrl, ref[t.astype(int)], rtol=0, atol=RESAMPLED_UM)


@pytest.mark.slow  # uses the fitted fixture (a whole selection, > 5 CPU s)
def test_cli_refuses_an_impossible_tolerance_then_forces(fitted, tmp_path, capsys):
    _, _, d = fitted
    out = tmp_path / "o"
    args = ["export", str(d / "m.json"), "--format", "drift", "--out", str(out), "--log", str(d / "log.csv"),
            "--sample-period-s", "120", "--tolerance-um", str(IMPOSSIBLE_UM)]
    assert main(args) == 2
    assert not out.exists()
    captured = capsys.readouterr()
    assert "tolerance not met" in captured.err and "model residual" in captured.out
    assert main(args + ["--force"]) == 0
    info = json.loads((out / "export.json").read_text())
    assert info["override"]["forced"] is True and info["tolerance_met"] is False
    assert info["sample_period_s"] == 120.0 and info["check_log_median_step_s"] == 60.0
    assert info["worst_model_residual_um"] > IMPOSSIBLE_UM
    assert sorted(info["files"]) == [ex.DRIFT_FILE]
    back = ex.read_drift_coefficients(out / ex.DRIFT_FILE)
    assert set(back.gains) == set(info["check"]) == {"ch1", "ch2", "ch3", "ch4", "ch5"}


def test_cli_default_period_is_the_log_step_and_simulated_log_gives_the_true_residual(tmp_path):
    """With --sim the check runs on a simulated log (lumped, seed 0, sampled every 15 s) and reports
    the true residual (noise-free displacement − prediction) beside 'before' (the displacement)."""
    p = tmp_path / "m.json"
    one_filter_model(tau_s=1800.0, delay_s=30.0, coef=3.0, intercept_um=-60.0).save(p)
    out = tmp_path / "o"
    assert main(["export", str(p), "--format", "drift", "--out", str(out), "--tolerance-um", "1e-6",
                 "--sim", "lumped"]) == 0
    info = json.loads((out / "export.json").read_text())
    assert info["sample_period_s"] == 15.0 and info["sample_period_given"] is False
    r = info["check"]["ch1"]
    assert r["model"]["max_um"] <= ROUND_TRIP_UM
    assert set(r["true"]) == {"before", "volcomp", "volcomp_distance_rule", "controller"}
    assert r["true"]["controller"]["rms_um"] == pytest.approx(r["true"]["volcomp"]["rms_um"], abs=1e-6)


@pytest.mark.slow  # uses the fitted fixture (a whole selection, > 5 CPU s)
def test_bad_model_and_bad_coefficient_files_name_the_place(fitted, tmp_path, capsys):
    _, _, d = fitted
    obj = json.loads((d / "m.json").read_text())
    obj["schema_version"] = 2
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(obj))
    out = tmp_path / "o"
    assert main(["export", str(bad), "--format", "drift", "--out", str(out), "--log", str(d / "log.csv")]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert str(bad) in err and "key 'schema_version'" in err
    assert main(["export", str(d / "m.json"), "--format", "grid", "--out", str(out), "--log", str(d / "log.csv")]) == 2
    assert "--log applies to --format drift only" in capsys.readouterr().err
    p = ex.write_drift_coefficients(ex.drift_coefficients(one_filter_model(), 10.0), tmp_path, "hand")
    lines = p.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if s.startswith("f0,"))
    cells = lines[k].split(",")
    cells[6] = "1.5"                                                   # column 'a'
    lines[k] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=rf"row {k + 1}, column 'a': expected 0 <= a < 1"):
        ex.read_drift_coefficients(p)
