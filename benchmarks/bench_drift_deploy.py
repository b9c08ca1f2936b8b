"""The drift model the product deploys on the real log's judged split (issue 29): fitted on the whole shared part.

The real log's judgement fits on the first 60 % of the full 46 h log (``volcomp diagnose --drift full.csv
--fit-fraction 0.6``) and judges on the last 40 %. The first 60 % is exactly the shared file
(``../shared/data/thermal-log/log_first60.csv``, 6,669 rows = round(0.6 · 11,115)), and the selection reads
nothing after its fitting part (causal filters, folds inside the fitting part), so the model that judgement will
score can be fitted now: :class:`DriftSelector` on the shared file with every row in the fitting part and the
deployment's horizon (held-out / fitting length = 0.4 / 0.6). What cannot be known here is its future.

The script checks the equivalence it relies on: the same selection on the shared file padded to 11,115 rows (the
padding repeats the last row's inputs and displacements with the time running on; never read by the selection),
fitted with ``fit_fraction=0.6`` exactly as the command would, gives the same chosen candidates, weights, scales
and coefficients. Per channel it reports the chosen candidate and its fold figures beside OLS; where OLS is
returned, the candidate of largest mean log-gain over OLS and the gates it fails.

Run: ``python benchmarks/bench_drift_deploy.py`` → benchmarks/drift_deploy_results.md (about 25 CPU s).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import DriftLog, load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import DriftSelector, candidate_name  # noqa: E402
from errormap.io import atomic_write  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
FULL_ROWS = 11115          # the full log's rows (the shared README: 6,669 of 11,115)
JUDGED_FIT = 0.6           # the judgement's fit fraction of the full log


def padded(log: DriftLog, n_total: int) -> DriftLog:
    """``log`` followed by rows that repeat its last row's values, the time running on at its median step:
    (n_total,) rows; the padding stands in for the part of the full log that is not shared."""
    n = len(log.time_s)
    dt = float(np.median(np.diff(log.time_s)))
    t = np.concatenate([log.time_s, log.time_s[-1] + dt * np.arange(1, n_total - n + 1)])

    def ext(v):
        return np.concatenate([v, np.full(n_total - n, v[-1])])
    return DriftLog(t, {k: ext(v) for k, v in log.temps_c.items()}, {k: ext(v) for k, v in log.disp_um.items()},
                    None if log.speed_rpm is None else ext(log.speed_rpm), f"{log.path}+padding", dict(log.notes))


def failed_gates(sel: DriftSelector, stats: dict, ranking_ols: float) -> list:
    """The names of the selector's gates a candidate (its ``candidates_`` statistics) does not pass."""
    (ok_h, gain_h, _), (ok_n, gain_n, _) = stats["gate"]
    out = []
    if not stats["ranking"] < ranking_ols:
        out.append("ranking RMS not below OLS")
    if not ok_h:
        out.append("horizon gain ≤ 1 SE")
    if not ok_n:
        out.append("novelty gain ≤ 1 SE")
    if gain_h < sel.min_gain:
        out.append("horizon gain < 5 %")
    if gain_n < sel.min_gain:
        out.append("novelty gain < 5 %")
    if stats["worst_fold"] > sel.max_fold_loss:
        out.append(f"a fold {stats['worst_fold']:.2f}× OLS (> {sel.max_fold_loss:g})")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).with_name("drift_deploy_results.md")))
    a = ap.parse_args(argv)
    if not REAL.exists():
        print(f"skipped: the shared thermal log is absent ({REAL})")
        return
    log = load_drift_log(REAL)
    n = len(log.time_s)
    if round(JUDGED_FIT * FULL_ROWS) != n:
        raise SystemExit(f"expected the shared part to be round({JUDGED_FIT} · {FULL_ROWS}) rows, got {n}")
    t0 = time.process_time()
    # every shared row in the fitting part (round(f · n) = n), the deployment's horizon
    sel = DriftSelector(fit_fraction=1.0 - 0.4 / n, horizon=(1 - JUDGED_FIT) / JUDGED_FIT).fit(log)
    cpu = time.process_time() - t0
    assert len(sel.split(log)[0]) == n
    pad = padded(log, FULL_ROWS)
    ref = DriftSelector(fit_fraction=JUDGED_FIT).fit(pad)
    same = ref.chosen_ == sel.chosen_ and ref.shrink_ == sel.shrink_ and ref.scale_ == sel.scale_ and all(
        np.allclose(ref.model_.channels[ch].coef, sel.model_.channels[ch].coef, rtol=1e-9, atol=1e-12)
        for ch in sel.chosen_)
    if not same:
        raise SystemExit("the selection on the padded log differs from the one on the shared part: the "
                         "equivalence this bench relies on does not hold")
    L = ["# The drift model the product deploys on the real log's judged split (issue 29)", "",
         "`python benchmarks/bench_drift_deploy.py`: `DriftSelector` fitted on the whole shared part (the first 60 % "
         f"of the full log, {n} rows), the deployment's horizon 0.4 / 0.6 — the model that `volcomp diagnose --drift "
         "full.csv --fit-fraction 0.6` fits; checked: the same choices, weights, scales and coefficients on the shared "
         f"part padded to {FULL_ROWS} rows with `fit_fraction=0.6`. Its future (the last 40 %) is not here. Fold "
         "figures: RMS of the MEASURED residual on the validation rows (μm), chosen / OLS; worst fold: the largest "
         "RMS ratio to OLS over the ranking, horizon and novelty folds. CPU per selection: "
         f"{cpu:.0f} s.", "",
         "| channel | chosen | s | ranking | horizon | novelty | worst fold | candidates passing every gate |",
         "|---|---|---|---|---|---|---|---|"]
    misses = []
    for ch, (f, hy) in sel.chosen_.items():
        c = sel.candidates_[ch]
        k = (f, hy, sel.shrink_[ch])
        st, o = c[k], c[("ols", "", 1.0)]
        sc = sel.scale_[ch]
        s_txt = "∞" if sc in (None, np.inf) else f"{sc:g}"
        L.append(f"| {ch} | {candidate_name(*k)} | {s_txt} | {st['ranking']:.2f} / "
                 f"{o['ranking']:.2f} | {st['horizon']:.2f} / {o['horizon']:.2f} | {st['novelty']:.2f} / "
                 f"{o['novelty']:.2f} | {st['worst_fold']:.2f} | {len(sel.eligible_[ch])} |")
        if f == "ols":
            best = max((kk for kk in c if kk[0] != "ols"), key=lambda kk: c[kk]["gain"])
            b = c[best]
            ratios = "; ".join(", ".join(f"{x:.2f}" for x in fold) for fold in b["fold_ratios"])
            misses.append(f"- {ch}: OLS returned. The candidate of largest mean log-gain over OLS, "
                          f"{candidate_name(*best)} "
                          f"(ranking {b['ranking']:.2f} / {o['ranking']:.2f}, horizon {b['horizon']:.2f} / "
                          f"{o['horizon']:.2f}, novelty {b['novelty']:.2f} / {o['novelty']:.2f} μm; fold ratios to "
                          f"OLS, ranking; horizon; novelty: {ratios}), fails: "
                          f"{', '.join(failed_gates(sel, b, o['ranking'])) or 'none'}.")
    L += [""] + (misses or ["Every channel returns a candidate other than OLS."]) + [""]
    with atomic_write(a.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
