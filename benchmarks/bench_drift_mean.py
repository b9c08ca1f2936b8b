"""The constant-offset candidate (the fitting part's mean per channel) beside OLS in the drift selection: before/after.

Per log, two whole selections on the same fitting part: **before** — the default families without ``mean``;
**after** — the default (``mean`` among the candidates, and no candidate returned that loses to the mean in any
validation set where the mean itself passes every gate against OLS). Judged on the held-out part: RMS of the
MEASURED residual (displacement − prediction) beside OLS and the plain mean, and on simulated logs the TRUE residual
(noise-free displacement − prediction) too.

Data: the real log's pseudo-futures (the shared first 60 % of the 46 h log, fit on its first 60 % / 80 % = 0–36 % /
0–48 % of the full log, judged on the rest of the shared part, as ``bench_drift_regime.py``), and the simulated logs
of ``bench_drift_regime.py`` (both simulator families, regime change at 60 %, sampled every 60 s, fit on 60 %).

Run: ``python benchmarks/bench_drift_mean.py --seeds 0-4 --partial FILE`` (one JSON line per finished log, resumed)
→ benchmarks/drift_mean_results.md.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import DriftSelector, default_families  # noqa: E402
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import atomic_write, write_csv  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
REAL_SPLITS = (0.6, 0.8)      # of the shared part: 0–36 % → 36–60 %, 0–48 % → 48–60 % of the full log
SIM_SPLIT = 0.6
SIM_DT_S = 60.0
TOLERATED_LOSS = 1.05


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def _without_mean():
    return [f for f in default_families() if f.name != "mean"]


def case(log, ff, truth=None):
    """Per channel and variant (before: without the mean candidate; after: the default): chosen model and held-out
    RMS of the measured (and, with ``truth``, the true) residual, beside OLS and the fitting part's mean."""
    out = {}
    for variant, fams in (("before", _without_mean()), ("after", None)):
        t0 = time.process_time()
        sel = DriftSelector(fit_fraction=ff, families=fams).fit(log)
        rep = sel.report(log)
        fit, hold = sel.split(log)
        pred = sel.model_.predict(log, sel.cache_)
        cpu = time.process_time() - t0
        for ch, r in rep.items():
            m = float(np.mean(log.disp_um[ch][fit]))
            row = out.setdefault(ch, {"channel": ch, "ols": r["rms_ols_um"], "mean": r["rms_mean_um"]})
            row[variant] = {"model": r["model"], "rms": r["rms_after_um"], "cpu_s": cpu}
            if truth is not None:
                clean = truth["clean_um"][ch][hold]
                row[variant]["true"] = _rms(clean - pred[ch][hold])
                row["true_mean"] = _rms(clean - m)
    return list(out.values())


def sim_log(family, seed):
    cols = SIMULATORS[family](seed, dt_s=SIM_DT_S, shift_at=SIM_SPLIT)
    truth = cols.pop("_truth")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, cols)       # read back the way the command reads a log
        return load_drift_log(path), truth


def render(rows, out):
    L = ["# The constant-offset candidate in the drift selection: before / after", "",
         "`python benchmarks/bench_drift_mean.py --seeds 0-4 --partial FILE`. Held-out RMS of the MEASURED residual "
         "(μm) and its ratio to OLS; before = the default families without `mean`, after = the default. "
         "`mean` = the fitting part's mean held out (the plainest baseline).", "",
         "| log | channel | OLS | mean | before: chosen | before | after: chosen | after | after / before |",
         "|---|---|---|---|---|---|---|---|---|"]
    groups = {}
    for r in rows:
        b, a = r["before"], r["after"]
        L.append(f"| {r['log']} | {r['channel']} | {r['ols']:.3g} | {r['mean']:.3g} | {b['model']} | {b['rms']:.3g} "
                 f"({b['rms'] / r['ols']:.3f}×) | {a['model']} | {a['rms']:.3g} ({a['rms'] / r['ols']:.3f}×) | "
                 f"{a['rms'] / b['rms']:.3f} |")
        groups.setdefault(r["log"].split(" ")[0], []).append(r)
    L += ["", "| data | cases | changed | better (< 0.9995×) | worse (> 1.0005×) | worst after/before | "
          "> 1.05× OLS before → after | mean beats OLS held out | geometric mean ratio to OLS before → after | CPU s |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for g, rr in groups.items():
        q = np.array([r["after"]["rms"] / r["before"]["rms"] for r in rr])
        qb = np.array([r["before"]["rms"] / r["ols"] for r in rr])
        qa = np.array([r["after"]["rms"] / r["ols"] for r in rr])
        cpu = sum({(r["log"]): r["before"]["cpu_s"] + r["after"]["cpu_s"] for r in rr}.values())
        L.append(f"| {g} | {len(rr)} | {sum(r['before']['model'] != r['after']['model'] for r in rr)} | "
                 f"{int((q < 0.9995).sum())} | {int((q > 1.0005).sum())} | {q.max():.3f} | "
                 f"{int((qb > TOLERATED_LOSS).sum())} → {int((qa > TOLERATED_LOSS).sum())} | "
                 f"{sum(r['mean'] < r['ols'] for r in rr)} | {np.exp(np.mean(np.log(qb))):.3f} → "
                 f"{np.exp(np.mean(np.log(qa))):.3f} | {cpu:.0f} |")
    tr = [r for r in rows if "true" in r["after"]]
    changed = [r for r in tr if r["before"]["model"] != r["after"]["model"]]
    if tr:
        L += ["", "Simulated logs, TRUE residual (noise-free displacement − prediction), after / before, changed cases: " +
              (", ".join(f"{r['log']} {r['channel']} {r['after']['true'] / r['before']['true']:.3f}" for r in changed)
               or "none") + "."]
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L) + "\n")
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-4", help="simulated seeds LO-HI of both families (the benchmark's: 0-9)")
    ap.add_argument("--partial", default=None, help="one JSON line per finished log (resumed)")
    ap.add_argument("--out", default=str(Path(__file__).with_name("drift_mean_results.md")))
    ap.add_argument("--no-real", action="store_true", help="simulated logs only")
    ap.add_argument("--render", nargs="*", default=None, metavar="PARTIAL",
                    help="only render these partial files (one JSON line per log) to --out")
    a = ap.parse_args(argv)
    if a.render is not None:
        rows = [r for f in a.render for line in Path(f).read_text().splitlines() if line.strip() for r in json.loads(line)]
        print("\n".join(render(rows, a.out)))
        return
    lo, hi = (int(x) for x in a.seeds.split("-"))
    todo = ([("real", ff) for ff in REAL_SPLITS] if REAL.exists() and not a.no_real else []) + \
        [(fam, s) for s in range(lo, hi + 1) for fam in ("lumped", "rod")]
    if not REAL.exists():
        print(f"the real log is absent ({REAL}): simulated logs only", file=sys.stderr)
    rows, done = [], set()
    if a.partial and Path(a.partial).exists():
        for line in Path(a.partial).read_text().splitlines():
            if line.strip():
                rr = json.loads(line)
                rows += rr
                done.add(rr[0]["log"])
    real = load_drift_log(REAL) if REAL.exists() else None
    for kind, x in todo:
        name = f"real fit {x:.0%} of the shared part" if kind == "real" else f"{kind} seed {x}"
        if name in done:
            continue
        log, truth = (real, None) if kind == "real" else sim_log(kind, x)
        rr = [dict(r, log=name) for r in case(log, x if kind == "real" else SIM_SPLIT, truth)]
        rows += rr
        if a.partial:
            with open(a.partial, "a", encoding="utf-8") as fh:
                fh.write(json.dumps(rr) + "\n")
        print(f"{name}: " + ", ".join(f"{r['channel']} {r['before']['model']} → {r['after']['model']} "
                                      f"{r['after']['rms'] / r['before']['rms']:.3f}" for r in rr),
              file=sys.stderr, flush=True)
    print("\n".join(render(rows, a.out)))


if __name__ == "__main__":
    main()
