"""Development aid for the drift selection rule (issue 14, round 2): per log and split, the per-fold
validation RMS of EVERY candidate under several fold schemes, and each candidate's held-out RMS after
refitting on the whole fitting part. Selection rules are then compared offline on the saved JSON
(`--rules`), on a development seed range that is not the benchmark's (seeds 100…).

Run: ``python benchmarks/dev_drift_rules.py --seed0 100 --seeds 10 --jobs 16 --out dev.json``;
``python benchmarks/dev_drift_rules.py --rules dev.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import (PLSTowardOLSFamily, RidgeTowardOLSFamily, cv_residuals,  # noqa: E402
                                             default_families, feature_matrix,
                                             horizon_folds, rolling_origin_folds)
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import write_csv, write_json  # noqa: E402

SPLITS = (0.6, 0.8)


SCHEMES = ["short4", "hor4", "hor6"]


def schemes(n_fit, ff):
    h = (1 - ff) / ff
    allf = {"short4": lambda: rolling_origin_folds(n_fit, 4, 0.5), "hor4": lambda: horizon_folds(n_fit, h, 4, 0.5),
            "hor6": lambda: horizon_folds(n_fit, h, 6, 0.4)}
    return {k: allf[k]() for k in SCHEMES}


def _set_schemes(names):
    SCHEMES[:] = names


def one(args):
    family, seed = args
    cols = SIMULATORS[family](seed)
    cols.pop("_truth")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, cols)
        log = load_drift_log(path)
    chans = list(log.disp_um)
    out = []
    for ff in SPLITS:
        t0 = time.perf_counter()
        n = len(log.time_s)
        n_fit = int(round(ff * n))
        fit, hold = np.arange(n_fit), np.arange(n_fit, n)
        cache = {}
        fams = default_families() + [RidgeTowardOLSFamily(), PLSTowardOLSFamily()]
        rec = {}
        for name, folds in schemes(n_fit, ff).items():
            res = cv_residuals(log, fams, chans, folds, cache)
            for (ch, f, h), rs in res.items():
                if len(rs) == len(folds):
                    rec.setdefault((ch, f, h), {})[name] = [float(np.sqrt(np.mean(r**2))) for r in rs]
        for fam in fams:
            for ch, hyp in fam.fit(log, chans, fit, cache).items():
                for h, (feats, a, b) in hyp.items():
                    r = log.disp_um[ch][hold] - a - feature_matrix(log, feats, cache)[hold] @ b
                    if (ch, fam.name, h) in rec:
                        rec[(ch, fam.name, h)]["held"] = float(np.sqrt(np.mean(r**2)))
        out.append({"family": family, "seed": seed, "split": ff, "fit_s": time.perf_counter() - t0,
                    "cands": [{"ch": ch, "fam": f, "hyper": h, **v} for (ch, f, h), v in rec.items()]})
    return out


def _pooled(rms):
    """Pooled RMS over equal-length validation blocks, from their per-block RMS values."""
    return float(np.sqrt(np.mean(np.square(rms))))


def apply_rule(cands, families, gate_se=1.0, rank="short4", horizon="hor4"):
    """The selector's rule on saved candidates of one channel: the best-ranked candidate (pooled RMS on
    the ranking folds) among ``families`` that scores below OLS there and beats OLS on the horizon folds
    by more than ``gate_se`` standard errors of the per-fold log gain; else OLS. Returns the candidate."""
    ols = next(c for c in cands if c["fam"] == "ols")
    pool = [c for c in cands if c["fam"] in families and rank in c and horizon in c and "held" in c]
    pool.sort(key=lambda c: _pooled(c[rank]))
    for c in pool:
        if c["fam"] == "ols":
            continue
        if _pooled(c[rank]) >= _pooled(ols[rank]):
            break
        d = np.log(ols[horizon]) - np.log(c[horizon])
        se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else 0.0
        if d.mean() > gate_se * se:
            return c
    return ols


def compare_rules(path, family_sets):
    """Markdown rows: per family set, counts of held-out RMS below / above OLS, worst ratio, geometric mean."""
    rows = json.loads(Path(path).read_text())["rows"]
    lines = ["| families | < OLS | > OLS | worst ratio | gm | cases |", "|---|---|---|---|---|---|"]
    for fams in family_sets:
        below = above = 0
        ratios = []
        for r in rows:
            by_ch = {}
            for c in r["cands"]:
                by_ch.setdefault(c["ch"], []).append(c)
            for ch, cands in by_ch.items():
                ols = next(c for c in cands if c["fam"] == "ols")
                pick = apply_rule(cands, fams)
                q = pick["held"] / ols["held"]
                ratios.append(q)
                below += q < 1 - 1e-12
                above += q > 1 + 1e-12
        ratios = np.array(ratios)
        lines.append(f"| {', '.join(fams)} | {below} | {above} | {ratios.max():.2f} | "
                     f"{np.exp(np.mean(np.log(ratios))):.3f} | {len(ratios)} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--rules", help="compare selection rules offline on a saved JSON instead of running")
    ap.add_argument("--seed0", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="dev_drift_rules.json")
    ap.add_argument("--schemes", default=",".join(SCHEMES))
    a = ap.parse_args(argv)
    if a.rules:
        base = ["ols", "subset_lag", "ridge_bank", "pls_bank", "transfer"]
        print(compare_rules(a.rules, [base, ["ols", "subset_lag", "transfer", "ridge_ols", "pls_ols"],
                                      base + ["ridge_ols", "pls_ols"], ["ols", "ridge_ols", "pls_ols"],
                                      ["ols", "subset_lag", "ridge_ols", "pls_ols"],
                                      ["ols", "transfer", "ridge_ols", "pls_ols"]]))
        return
    SCHEMES[:] = a.schemes.split(",")
    tasks = [(f, s) for f in SIMULATORS for s in range(a.seed0, a.seed0 + a.seeds)]
    rows = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs, initializer=_set_schemes, initargs=(list(SCHEMES),)) as ex:
        for r in ex.map(one, tasks):
            rows += r
    write_json(a.out, {"wall_s": time.perf_counter() - t0, "rows": rows})


if __name__ == "__main__":
    main()
