"""Drift logs: sensor selection with a lag, before/after, bad input."""
import json

import numpy as np
import pytest

from compensation.cli import main
from errormap.diagnosis.drift import DriftModeller, load_drift_log, simulate_drift_log
from errormap.io import InputError, write_csv

NOISE_UM = 0.5
LAG_S = 300.0
LAG_TOL_S = 20.0          # two sampling steps
RMS_NOISE_FACTOR = 1.2    # held-out RMS after ≤ this × noise


def _log(tmp_path, seed, **kw):
    cols = simulate_drift_log(seed, lag_s=LAG_S, noise_um=NOISE_UM, **kw)
    truth = cols.pop("_truth")
    write_csv(tmp_path / "log.csv", cols)
    return tmp_path / "log.csv", truth


@pytest.mark.parametrize("seed", [0, 2])
def test_two_active_sensors_and_the_lag_are_found(tmp_path, seed):
    path, truth = _log(tmp_path, seed)
    log = load_drift_log(path)
    m = DriftModeller().fit(log)
    rep = m.report(log)
    for ch, k in truth.items():
        r = rep[ch]
        assert sorted(r["sensors"]) == sorted(k)
        assert r["regressors"] == r["sensors"]
        assert abs(r["lag_s"] - LAG_S) <= LAG_TOL_S
        assert r["rms_after_um"] <= RMS_NOISE_FACTOR * NOISE_UM
        assert r["rms_after_um"] < 0.2 * r["rms_before_um"]
        for s, kk in k.items():
            assert abs(r["coefficients"][f"{s}_um_per_c"] - kk) < 0.05 * abs(kk)


def test_drift_cli(tmp_path, capsys):
    path, truth = _log(tmp_path, 1)
    out = tmp_path / "out"
    assert main(["diagnose", "--drift", str(path), "--out", str(out)]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert set(d["channels"]) == set(truth)
    for ch, c in d["channels"].items():
        for k in ("sensors", "lag_s", "rms_before_um", "rms_after_um", "max_before_um", "max_after_um"):
            assert k in c
        assert sorted(c["sensors"]) == sorted(truth[ch])
    assert "data:image/png;base64," in (out / "report.html").read_text()


@pytest.mark.parametrize("case", ["time", "nan", "kelvin", "no_temp"])
def test_bad_drift_log(tmp_path, case, capsys):
    cols = simulate_drift_log(0, n=200)
    cols.pop("_truth")
    if case == "time":
        cols["time_s"][50] = cols["time_s"][49]
        want = ("row 52", "time_s")
    elif case == "nan":
        cols["temp_s3_c"][10] = np.nan
        want = ("row 12", "temp_s3_c")
    elif case == "kelvin":
        cols["temp_s1_c"] = cols["temp_s1_c"] + 273.15
        want = ("row 2", "temp_s1_c")
    else:
        for k in [k for k in cols if k.startswith("temp_")]:
            cols.pop(k)
        want = ("temp_<sensor>_c",)
    write_csv(tmp_path / "log.csv", cols)
    with pytest.raises(InputError) as exc:
        load_drift_log(tmp_path / "log.csv")
    for w in want:
        assert w in str(exc.value)
    out = tmp_path / "out"
    assert main(["diagnose", "--drift", str(tmp_path / "log.csv"), "--out", str(out)]) == 2
    assert not out.exists()
