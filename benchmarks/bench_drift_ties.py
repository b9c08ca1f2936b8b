"""The real log's two ties (issue 29, sixth round, step 2): does a grey-box first-order response per input with
non-negative (sign-oriented) gains clear the selection's gates on the fitting part?

The family: ``ThermalNNFamily(taus=(0, τ))`` — every input as logged (feed-through) and through ONE first-order lag of
time constant τ (15 min, 1 h or 3 h: one thermal state per input, τ shared), each input oriented by the sign of its
OLS coefficient and its gains constrained ≥ 0 (non-negative least squares, ridge λ as the default ``thermal_nn``'s).
Measured on the real log fitted on its first 36 % (``DriftSelector(fit_fraction=0.6)`` on the shared 60 %), only the
fold statistics of the fitting part are read (the held-out 36–60 % is never looked at here): per tie channel the
candidates of largest horizon mean log-gain over OLS, with the gates' numbers.

Run: ``python benchmarks/bench_drift_ties.py`` → benchmarks/drift_ties_results.md (about 15 CPU s). Skips without
the shared log.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import MIN_GAIN, DriftSelector, OLSFamily, ThermalNNFamily  # noqa: E402
from errormap.io import atomic_write  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
TAUS_S = (900.0, 3600.0, 10800.0)
TIES = ("ch1", "ch2")
FIT_FRACTION = 0.6        # of the shared 60 %: the benchmark's 0–36 % split
TOP = 6


def families():
    fams = [OLSFamily()]
    for tau in TAUS_S:
        f = ThermalNNFamily(taus=(0.0, tau))
        f.name = f"greybox_nn_{int(tau)}"
        fams.append(f)
    return fams


def main(out=Path(__file__).with_name("drift_ties_results.md")):
    if not REAL.exists():
        print(f"skipped: {REAL} not found")
        return 0
    t0 = time.process_time()
    sel = DriftSelector(fit_fraction=FIT_FRACTION, families=families()).fit(load_drift_log(REAL))
    cpu = time.process_time() - t0
    L = ["# The real log's ties at the 36 % split: a non-negative grey-box family (issue 29, sixth round)", "",
         "`python benchmarks/bench_drift_ties.py` — the family `greybox_nn_<τ>`: every input as logged and through one "
         "first-order lag of τ, gains sign-oriented by OLS and non-negative; OLS and this family only, fitted on the "
         "first 36 % of the log; fold statistics of the fitting part only (the held-out part is not read). Horizon "
         f"and novelty: mean log-gain over OLS ± its SE (the gate: > 1 SE and ≥ {MIN_GAIN:.3f}); worst fold: the "
         f"largest RMS ratio to OLS over all folds (the bound: 1.05). CPU {cpu:.0f} s.", ""]
    for ch in TIES:
        L += [f"## {ch}: chosen {sel.chosen_[ch][0]} (eligible: {', '.join(sel.eligible_[ch]) or 'none'})", "",
              "| candidate | horizon | novelty | worst fold |", "|---|---|---|---|"]
        for k, g in sorted(sel.gate_[ch].items(), key=lambda kv: -kv[1][1])[:TOP]:
            L.append(f"| {k} | {g[1]:+.3f} ± {g[2]:.3f} | {g[3]:+.3f} ± {g[4]:.3f} | {sel.worst_fold_[ch][k]:.2f} |")
        L.append("")
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
