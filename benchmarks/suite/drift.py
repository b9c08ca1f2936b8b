"""Thermal drift on a real machine tool's log: the selected model beside both plain baselines.

The first 60 % of a real 46 h machine-tool log (15 s sampling, shared data; the benchmark records no figure
where it is absent). Fit on its first 80 %, judge on the rest, blocked by time (the selection reads its fitting
part only). Per channel: held-out RMS of the MEASURED residual of no compensation, the constant offset (the fit
part's mean), OLS on every temperature and the speed, and the model :class:`DriftSelector` chooses.
"""
from __future__ import annotations

from pathlib import Path

from errormap.diagnosis.drift import DriftLog, load_drift_log
from errormap.diagnosis.drift_models import DriftSelector

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
FIT_FRACTION = 0.8

TITLE = "Thermal drift on a real machine-tool log: the chosen model beside the constant offset and OLS"
DATA = ("the first 60 % of a real 46 h machine-tool log (15 s sampling, 6,669 rows), fitted on its first 80 %, "
        "judged on the last 20 % (quick: the first 2,000 rows)")


def head(log: DriftLog, n: int) -> DriftLog:
    """The first ``n`` rows of ``log``."""
    return DriftLog(log.time_s[:n], {k: v[:n] for k, v in log.temps_c.items()}, {k: v[:n] for k, v in log.disp_um.items()},
                    None if log.speed_rpm is None else log.speed_rpm[:n], log.path, dict(log.notes))


def run(quick: bool, seed: int) -> dict:
    if not REAL.exists():
        return {"figures": [], "notes": ["The real thermal log is absent on this machine: no figure."]}
    log = load_drift_log(REAL)
    if quick:
        log = head(log, 2_000)
    sel = DriftSelector(fit_fraction=FIT_FRACTION).fit(log)
    figs = []
    for ch, c in sel.report(log).items():
        figs.append({"what": f"{ch}: chosen `{c['model']}`, held-out RMS", "value": c["rms_after_um"], "unit": "μm",
                     "residual": "measured", "anchor": "OLS on every input", "anchor_value": c["rms_ols_um"]})
        figs.append({"what": f"{ch}: constant offset (the fit part's mean), held-out RMS", "value": c["rms_constant_um"],
                     "unit": "μm", "residual": "measured", "anchor": "no compensation", "anchor_value": c["rms_before_um"]})
    return {"figures": figs, "notes": []}
