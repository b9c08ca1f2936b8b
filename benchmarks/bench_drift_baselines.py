"""The drift selection beside both plain baselines on the real thermal log: the constant offset, OLS, the chosen model.

Fit on the first ``f`` of the shared part (the first 60 % of a real machine tool's 46 h log), judge on the rest,
blocked by time (the selection reads its fitting part only). Per channel: held-out RMS of the MEASURED residual
(μm) of no compensation, the constant offset (the fitting part's mean), OLS on every temperature and the speed, and
the chosen model of the default selection (the constant among its candidates, the plainest-baseline rule); beside,
the choice of the same selection without the constant candidate (the rule before it), and the constant's mean
log-gain over OLS on the validation folds (the selection's score; > 0: the constant wins the validation).

Run: ``python benchmarks/bench_drift_baselines.py [--fractions 0.8 0.6]`` (about 15 CPU s per selection).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import DriftSelector, default_families  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"


def table(log, frac: float) -> list:
    """Markdown rows of one split: per channel the held-out RMS of every baseline and of the chosen models."""
    t0 = time.process_time()
    sel = DriftSelector(fit_fraction=frac).fit(log)
    cpu = time.process_time() - t0
    old = DriftSelector(fit_fraction=frac, families=[f for f in default_families() if f.name != "constant"]).fit(log)
    rep, rep_old = sel.report(log), old.report(log)
    fit, hold = sel.split(log)
    L = [f"Fit on rows 0–{len(fit) - 1} ({frac:.0%} of the shared part), judged on the last {len(hold)} rows; "
         f"CPU per selection {cpu:.0f} s.", "",
         "| channel | none | constant | OLS | chosen (with the constant) | RMS | without the constant | RMS | "
         "constant's validation gain over OLS |",
         "|---|---|---|---|---|---|---|---|---|"]
    for ch, c in rep.items():
        o = rep_old[ch]
        L.append(f"| {ch} | {c['rms_before_um']:.2f} | {c['rms_constant_um']:.2f} | {c['rms_ols_um']:.2f} | "
                 f"{c['model']} | {c['rms_after_um']:.2f} | {o['model']} | {o['rms_after_um']:.2f} | "
                 f"{c['selection_score_constant']:+.2f} |")
    best = {ch: min(("constant", c["rms_constant_um"]), ("OLS", c["rms_ols_um"]), key=lambda x: x[1])
            for ch, c in rep.items()}
    L += ["", "Better plain baseline held out: " + ", ".join(f"{ch} {b[0]}" for ch, b in best.items())
          + f"; chosen / OLS geometric mean {np.exp(np.mean([np.log(c['rms_after_um'] / c['rms_ols_um']) for c in rep.values()])):.3f}.", ""]
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.8])
    a = ap.parse_args(argv)
    if not REAL.exists():
        print(f"skipped: the shared thermal log is absent ({REAL})")
        return
    log = load_drift_log(REAL)
    for f in a.fractions:
        print("\n".join(table(log, f)))


if __name__ == "__main__":
    main()
