"""Drift-coefficient export: what the controller's fixed sample period leaves, against the model and the truth.

    python benchmarks/bench_export_drift.py [--seeds 1] [--jobs 1] [--periods 1,5,15,20,60,300]
                                            [--out benchmarks/export_drift_results.md]

The user's path, per simulator family (``lumped`` 46 h at 15 s, ``rod`` 40 h at 20 s: two
independent generators, ``errormap/diagnosis/drift_sim.py``) and seed: simulate the log → fit the
drift model as ``volcomp diagnose --drift`` does (``DriftSelector``, first 60 % by time) → export
the coefficients at each sample period → re-simulate the controller from the written file alone
(``compensation.export.check_drift_export``'s controller) on the same log.

Reported per period: the **model residual** (controller − ``DriftModel.predict``; max over
channels and the whole log) and, on the held-out last 40 %, the **true residual** RMS (noise-free
displacement − prediction; mean over channels) for no compensation ('before'), the OLS baseline,
volcomp's model, and the controller running the exported coefficients.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from compensation import export as ex  # noqa: E402
from errormap.diagnosis.drift import DriftLog  # noqa: E402
from errormap.diagnosis.drift_models import DriftSelector  # noqa: E402
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import atomic_write, write_json  # noqa: E402


def _rms(v):
    return float(np.sqrt(np.mean(np.asarray(v) ** 2)))


def run_one(family: str, seed: int, periods) -> list[dict]:
    cols = SIMULATORS[family](seed, n_dropouts=0)
    clean = cols.pop("_truth")["clean_um"]
    log = DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                   {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols["speed_rpm"], f"{family}-{seed}")
    t0 = time.perf_counter()
    sel = DriftSelector(fit_fraction=0.6).fit(log)
    fit_s = time.perf_counter() - t0
    _, hold = sel.split(log)
    model = sel.model_
    pred, ols = model.predict(log), sel.baseline_.predict(log)
    step = float(np.median(np.diff(log.time_s)))
    rows = []
    for dt in periods:
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            res = ex.export_drift_coefficients(model, tmp, dt, log, "bench", tolerance_um=np.inf, clean_um=clean)
            ctrl = ex.controller_drift_at(res["coefficients"], log)
        chans = list(model.channels)
        rows.append({
            "family": family, "seed": seed, "log_step_s": step, "period_s": dt, "fit_s": fit_s,
            "model_max_um": res["worst_model_residual_um"],
            "model_rms_um": float(np.mean([res["check"][c]["model"]["rms_um"] for c in chans])),
            "true_rms_um": {k: float(np.mean([_rms(clean[c][hold] - (0 if p is None else p[c][hold])) for c in chans]))
                            for k, p in (("before", None), ("ols", ols), ("volcomp", pred), ("controller", ctrl))},
            "seconds": time.perf_counter() - t0})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--periods", default="1,5,15,20,60,300")
    ap.add_argument("--out", default=str(Path(__file__).with_name("export_drift_results.md")))
    args = ap.parse_args(argv)
    periods = [float(p) for p in args.periods.split(",")]
    jobs = [(f, s, periods) for f in ("lumped", "rod") for s in range(args.seeds)]
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            res = list(pool.map(run_one, *zip(*jobs)))
    else:
        res = [run_one(*j) for j in jobs]
    rows = [r for rs in res for r in rs]
    wall = time.perf_counter() - t0
    cmd = "python benchmarks/bench_export_drift.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = [f"# Drift-coefficient export: sample period vs residual", "",
             f"`{cmd.strip()}` — {platform.machine()}, {os.cpu_count()} cores shared with other jobs, {wall:.0f} s.",
             "Model residual: controller (from the written coefficients) − DriftModel.predict, max over channels "
             "and the whole log / mean over channels of the RMS. True residual: RMS of noise-free displacement − "
             "prediction on the held-out last 40 %, mean over channels.", "",
             "| family | seed | log step s | controller period s | model residual max / RMS μm | true RMS μm: "
             "before | OLS | volcomp | controller |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t = r["true_rms_um"]
        lines.append(f"| {r['family']} | {r['seed']} | {r['log_step_s']:g} | {r['period_s']:g} | "
                     f"{r['model_max_um']:.3g} / {r['model_rms_um']:.3g} | {t['before']:.3g} | {t['ols']:.3g} | "
                     f"{t['volcomp']:.3g} | {t['controller']:.3g} |")
    out = Path(args.out)
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    write_json(out.with_suffix(".json"), {"command": cmd, "wall_s": wall, "rows": rows})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
