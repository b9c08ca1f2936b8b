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


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed0", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="dev_drift_rules.json")
    ap.add_argument("--schemes", default=",".join(SCHEMES))
    a = ap.parse_args(argv)
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
