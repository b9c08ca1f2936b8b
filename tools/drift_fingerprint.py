"""Every figure of the default drift selection, to check that a change leaves the default unchanged.

``python tools/drift_fingerprint.py --out A.json`` on one commit, ``--out B.json`` on the other, then
``--compare A.json B.json``: the default ``DriftSelector(fit_fraction=0.6)`` on the shared real log (when present) and
on a simulated rod log (seed 6, 24 h at 120 s) — chosen candidates, weights, scales, the ranking / horizon / novelty
RMS of every candidate, the per-channel report and the coefficients — compared value by value to ``TOL`` (relative,
floor 1); keys present on one side only are listed apart (a removed report field).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import DriftLog, load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import DriftSelector  # noqa: E402
from errormap.diagnosis.drift_sim import simulate_rod_log  # noqa: E402
from errormap.io import atomic_write  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
TOL = 1e-9


def fingerprint(log) -> dict:
    sel = DriftSelector(fit_fraction=0.6).fit(log)
    out = {"chosen": sel.chosen_, "shrink": sel.shrink_, "scale": {k: str(v) for k, v in sel.scale_.items()},
           "cv": sel.cv_, "cvh": sel.cv_horizon_, "cvn": sel.cv_novelty_, "report": sel.report(log),
           "coef": {ch: [c.intercept_um] + list(map(float, c.coef)) for ch, c in sel.model_.channels.items()}}
    return json.loads(json.dumps(out, default=str))


def compare(a, b) -> tuple[list, set, int]:
    """(values differing beyond TOL, keys on one side only, values compared)."""
    bad, only, n = [], set(), [0]

    def walk(x, y, path):
        if isinstance(x, dict):
            for k in set(x) | set(y):
                if k not in x or k not in y:
                    only.add(f"{k} ({'first' if k in x else 'second'} only)")
                else:
                    walk(x[k], y[k], f"{path}/{k}")
        elif isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
            for i, (p, q) in enumerate(zip(x, y)):
                walk(p, q, f"{path}[{i}]")
        else:
            n[0] += 1
            same = x == y or (isinstance(x, float) and isinstance(y, (int, float)) and (
                (math.isnan(x) and math.isnan(y)) or abs(x - y) <= TOL * max(1.0, abs(x))))
            if not same:
                bad.append(f"{path}: {x!r} vs {y!r}")
    walk(a, b, "")
    return bad, only, n[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None)
    ap.add_argument("--compare", nargs=2, default=None)
    a = ap.parse_args(argv)
    if a.compare:
        bad, only, n = compare(*(json.loads(Path(p).read_text()) for p in a.compare))
        print(f"values compared: {n}; differing beyond {TOL:g}: {len(bad)}; keys on one side only: {sorted(only)}")
        print("\n".join(bad[:30]))
        return 1 if bad else 0
    res = {}
    if REAL.exists():
        res["real"] = fingerprint(load_drift_log(REAL))
    cols = simulate_rod_log(6, hours=24, dt_s=120, n_dropouts=0)
    cols.pop("_truth")
    res["rod6"] = fingerprint(DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                                       {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols["speed_rpm"]))
    with atomic_write(a.out, "w", encoding="utf-8") as fh:
        json.dump(res, fh)
    return 0


if __name__ == "__main__":
    sys.exit(main())
