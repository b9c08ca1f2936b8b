"""Development seeds for the drift selection rule (issue 29): the rule is decided here, judged by bench_drift_regime.

The simulated logs of ``bench_drift_regime.py`` (both simulator families, the regime change from 60 % on) with
seeds DISJOINT from the benchmark's (default 100–109; the benchmark runs 0–9), fitted with
:class:`~errormap.diagnosis.drift_models.DriftSelector` under named rule variants, judged on the last 40 %:
held-out RMS of the MEASURED residual beside OLS, band coverage and median half-width. A rule change is
kept only when it helps here; its effect on the benchmark's seeds is then reported by bench_drift_regime.

Run: ``python benchmarks/bench_drift_dev.py --variants feature,raw`` → benchmarks/drift_dev_results.md (+ .json);
``--partial FILE`` appends every finished log as a JSON line.
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
from errormap.diagnosis.drift_models import DriftSelector  # noqa: E402
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import atomic_write, write_csv, write_json  # noqa: E402

SIM_SPLIT = 0.6
SIM_DT_S = 60.0
TOLERATED_LOSS = 1.05     # the bound: no channel worse than OLS by more than 5 % in any seed
VARIANTS = {"feature": {"feature_distance": True, "ranking_fold_loss": False},  # ρ = max(raw, the candidate's features)
            "raw": {"feature_distance": False, "ranking_fold_loss": False},     # ρ on the raw inputs (the rule before)
            "feature_rank": {"feature_distance": True, "ranking_fold_loss": True}}  # + the per-fold loss bound on
#                                                                                   the ranking folds (the default)


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def one(family, seed, variant):
    cols = SIMULATORS[family](seed, dt_s=SIM_DT_S, shift_at=SIM_SPLIT)
    cols.pop("_truth")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, cols)
        log = load_drift_log(path)
    t0 = time.process_time()
    sel = DriftSelector(fit_fraction=SIM_SPLIT, **VARIANTS[variant]).fit(log)
    rep = sel.report(log)
    cpu = time.process_time() - t0
    return [{"family": family, "seed": seed, "variant": variant, "channel": ch, "model": r["model"],
             "volcomp": r["rms_after_um"], "ols": r["rms_ols_um"], "coverage": r["band_coverage_heldout"],
             "halfwidth": r["band_halfwidth_heldout_median_um"], "cpu_s": cpu} for ch, r in rep.items()]


def render(rows, out):
    L = ["# Drift selection rule on development seeds (issue 29)", "",
         "`python benchmarks/bench_drift_dev.py` — simulated logs with the regime change from 60 % (as in "
         "bench_drift_regime), development seeds " + str(sorted({r["seed"] for r in rows})) + " (disjoint from the "
         "benchmark's 0–9); held-out MEASURED residual RMS, volcomp / OLS.", "",
         "| variant | cases | > OLS·1.05 | worst ratio (case) | < OLS | channels whose median ratio ≥ 1 | "
         "band coverage median, min | median half-width μm |", "|---|---|---|---|---|---|---|---|"]
    for v in dict.fromkeys(r["variant"] for r in rows):
        c = [r for r in rows if r["variant"] == v]
        ratio = [r["volcomp"] / r["ols"] for r in c]
        w = int(np.argmax(ratio))
        med = []
        for f, ch in dict.fromkeys((r["family"], r["channel"]) for r in c):
            q = [r["volcomp"] / r["ols"] for r in c if r["family"] == f and r["channel"] == ch]
            if np.median(q) >= 1 - 1e-9:
                med.append(f"{f} {ch} ({np.median(q):.3f})")
        L.append(f"| {v} | {len(c)} | {sum(x > TOLERATED_LOSS for x in ratio)} | {ratio[w]:.2f} ({c[w]['family']} "
                 f"s{c[w]['seed']} {c[w]['channel']} {c[w]['model']}) | {sum(x < 1 - 1e-9 for x in ratio)} | "
                 f"{'; '.join(med) or 'none'} | {np.median([r['coverage'] for r in c]):.2f}, "
                 f"{min(r['coverage'] for r in c):.2f} | {np.median([r['halfwidth'] for r in c]):.3g} |")
        bad = [r for r in c if r["volcomp"] > TOLERATED_LOSS * r["ols"]]
        if bad:
            L.append("")
            L.append(f"{v}: cases > OLS·1.05: " + "; ".join(f"{r['family']} s{r['seed']} {r['channel']} {r['model']} "
                                                        f"{r['volcomp'] / r['ols']:.2f}×" for r in bad))
            L.append("")
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L) + "\n")
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="100-109")
    ap.add_argument("--families", default="lumped,rod")
    ap.add_argument("--variants", default="feature,raw")
    ap.add_argument("--out", default=str(Path(__file__).with_name("drift_dev_results.md")))
    ap.add_argument("--partial", default=None)
    ap.add_argument("--from-partial", default=None)
    a = ap.parse_args(argv)
    if a.from_partial:
        rows = [r for line in Path(a.from_partial).read_text().splitlines() if line.strip() for r in json.loads(line)]
        print("\n".join(render(rows, a.out)))
        return
    lo, hi = (int(x) for x in a.seeds.split("-"))
    rows = []
    for v in a.variants.split(","):
        for f in a.families.split(","):
            for s in range(lo, hi + 1):
                r = one(f, s, v)
                rows += r
                if a.partial:
                    with open(a.partial, "a", encoding="utf-8") as fh:
                        fh.write(json.dumps(r) + "\n")
                worst = max(r, key=lambda x: x["volcomp"] / x["ols"])
                print(f"{v} {f} {s}: worst {worst['channel']} {worst['model']} {worst['volcomp'] / worst['ols']:.3f}",
                      file=sys.stderr, flush=True)
    write_json(Path(a.out).with_suffix(".json"), {"rows": rows})
    print("\n".join(render(rows, a.out)))


if __name__ == "__main__":
    main()
