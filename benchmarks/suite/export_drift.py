"""Drift-coefficient export: what the controller's fixed sample period leaves, against the model and the truth.

Per simulator family (``lumped`` 46 h at 15 s, ``rod`` 40 h at 20 s: two independent generators,
``errormap/diagnosis/drift_sim.py``): simulate the log, fit the drift model as ``volcomp diagnose --drift``
does (``DriftSelector``, first 60 % by time), export the coefficients at a sample period, re-simulate the
controller from the written file alone on the same log. Model residual: controller − ``DriftModel.predict``,
max over channels and the whole log. True residual: RMS of noise-free displacement − prediction on the
held-out last 40 %, mean over channels; anchor: the OLS baseline / no compensation.

    python -m benchmarks.run export_drift
"""
from __future__ import annotations

import tempfile

import numpy as np

from compensation import export as ex
from errormap.diagnosis.drift import DriftLog
from errormap.diagnosis.drift_models import DriftSelector
from errormap.diagnosis.drift_sim import SIMULATORS

PERIODS_S = (1.0, 5.0, 15.0, 20.0, 60.0, 300.0)
"""Controller sample periods of the full run; the quick run checks the lumped log's own step and 300 s."""
QUICK_HOURS = 12.0
"""Length of the quick run's lumped log (the full run: the family's own, 46 h / 40 h)."""

TITLE = "Drift-coefficient export: the controller's sample period vs the model's and the true residual"
DATA = ("simulated thermal-drift logs, `lumped` (46 h at 15 s) and `rod` (40 h at 20 s); model fitted as "
        "`diagnose --drift` does on the first 60 %; true residual on the held-out 40 %")


def _rms(v):
    return float(np.sqrt(np.mean(np.asarray(v) ** 2)))


def run_one(family: str, seed: int, periods, hours: float | None = None) -> list[dict]:
    """One simulated log (the family's own length, or ``hours``): per period the model residual (max μm) and
    the held-out true RMS of each predictor."""
    cols = SIMULATORS[family](seed, n_dropouts=0, **({} if hours is None else {"hours": hours}))
    clean = cols.pop("_truth")["clean_um"]
    log = DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                   {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols["speed_rpm"], f"{family}-{seed}")
    sel = DriftSelector(fit_fraction=0.6).fit(log)
    _, hold = sel.split(log)
    model = sel.model_
    pred, ols = model.predict(log), sel.baseline_.predict(log)
    chans = list(model.channels)
    true = lambda p: float(np.mean([_rms(clean[c][hold] - (0 if p is None else p[c][hold])) for c in chans]))  # noqa: E731
    rows = []
    for dt in periods:
        with tempfile.TemporaryDirectory() as tmp:
            res = ex.export_drift_coefficients(model, tmp, dt, log, "bench", tolerance_um=np.inf, clean_um=clean)
            ctrl = ex.controller_drift_at(res["coefficients"], log)
        rows.append({"family": family, "step_s": float(np.median(np.diff(log.time_s))), "period_s": dt,
                     "model_max_um": float(res["worst_model_residual_um"]), "before": true(None), "ols": true(ols),
                     "volcomp": true(pred), "controller": true(ctrl)})
    return rows


def run(quick: bool, seed: int) -> dict:
    """Full: both families at every period of ``PERIODS_S``; quick: a 12 h lumped log at 15 s and 300 s.

    Figures per family: the controller's held-out true RMS at the log's step, 60 s and 300 s (anchor: no
    compensation, the model and OLS beside it), and the worst model residual off the step; every period in the notes."""
    jobs = [("lumped", (15.0, 300.0))] if quick else [("lumped", PERIODS_S), ("rod", PERIODS_S)]
    hours = QUICK_HOURS if quick else None
    figs, notes = [], []
    for family, periods in jobs:
        rows = run_one(family, seed, periods, hours)
        step = rows[0]["step_s"]
        for r in rows:
            if r["period_s"] in (step, 60.0, 300.0):
                figs.append({"what": f"{family} (log step {step:g} s), controller at {r['period_s']:g} s: held-out RMS",
                             "value": r["controller"], "unit": "μm", "residual": "true",
                             "anchor": f"volcomp model {r['volcomp']:.3g}, OLS {r['ols']:.3g}, uncompensated",
                             "anchor_value": r["before"]})
        off = max((r for r in rows if r["period_s"] != step), key=lambda r: r["model_max_um"])
        at = next(r for r in rows if r["period_s"] == step)
        figs.append({"what": f"{family}: controller vs model, worst sample off the log step (at {off['period_s']:g} s)",
                     "value": off["model_max_um"], "unit": "μm", "residual": "model",
                     "anchor": "at the log's step (the model's own recursion)", "anchor_value": at["model_max_um"]})
        notes.append(f"{family}, controller vs model max / held-out true RMS by period: " + "; ".join(
            f"{r['period_s']:g} s {r['model_max_um']:.3g} / {r['controller']:.3g} μm" for r in rows))
    return {"figures": figs, "notes": notes}
