"""Drift models on a future that leaves the fit range (issue 29): the real log and simulated regime changes.

1. The real machine tool's log (``../shared/data/thermal-log/log_first60.csv``, the first 60 % of a
   46 h log; skipped with a note where absent). Per channel: the rolling-origin validation figures
   inside the fitting part (ranking, horizon and novelty folds: chosen model beside OLS), and the
   pseudo-future tests — fit on the first 36 % of the full log, judged on 36–60 % (``--fit-fraction
   0.6`` of the shared part), and fit on 48 %, judged on 48–60 % (``0.8``): held-out RMS of the
   MEASURED residual (displacement − prediction), volcomp beside plain OLS on every input.
2. Simulated logs whose later part leaves the fit range: both simulator families of
   ``errormap/diagnosis/drift_sim.py`` with ``shift_at`` = the fit fraction (from there on the spindle
   runs 1.3× faster and the ambient is 2 °C warmer), seeds 0..N−1, sampled every 60 s; fit on the
   first 60 %, judged on the last 40 %: measured residual beside OLS, and the TRUE residual
   (noise-free displacement − prediction).
3. The same simulated logs WITHOUT the regime change (``shift_at`` None: the later part runs as the
   fitting part did), fit on the first 60 %, judged on the rest — what ``bench_drift.py`` measured
   before issue 29 (it is folded in here and deleted): does the rule that protects against a new regime
   still beat OLS where there is none? Held-out band coverage is reported for both.

The user's path throughout: the log is written as CSV, loaded as `volcomp diagnose --drift` does,
DriftSelector chooses on the fitting part only, the held-out part judges.

Run: ``python benchmarks/bench_drift_regime.py --seeds 10 --no-shift`` → benchmarks/drift_regime_results.md
(+ .json); ``--partial FILE`` keeps every finished part, ``--from-partial FILE`` renders an interrupted run.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import BAND_GAMMAS, BAND_RULE, BAND_RULES, SHRINK_WEIGHTS, DriftSelector  # noqa: E402
from errormap.diagnosis.drift_sim import SHIFT_AMBIENT_C, SHIFT_SPEED, SIMULATORS  # noqa: E402
from errormap.io import atomic_write, write_csv, write_json  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
REAL_SPLITS = (0.6, 0.8)
SIM_SPLIT = 0.6
SIM_DT_S = 60.0
TOLERATED_LOSS = 1.05     # the bound: no channel worse than OLS by more than 5 % in any seed


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def real_rows():
    log = load_drift_log(REAL)
    out = []
    for ff in REAL_SPLITS:
        t0 = time.process_time()
        sel = DriftSelector(fit_fraction=ff).fit(log)
        for ch, r in sel.report(log).items():
            out.append({"split": ff, "channel": ch, "model": r["model"], "before": r["rms_before_um"],
                        "volcomp": r["rms_after_um"], "ols": r["rms_ols_um"],
                        "cv": r["cv_ranking_rms_um"], "cv_ols": r["cv_rms_ols_um"],
                        "cv_h": r["cv_horizon_rms_um"], "cv_h_ols": r["cv_horizon_rms_ols_um"],
                        "cv_n": r["cv_novelty_rms_um"], "cv_n_ols": r["cv_novelty_rms_ols_um"],
                        "band": r["band95_um"], "coverage": r["band_coverage_heldout"],
                        "halfwidth": r["band_halfwidth_heldout_median_um"], "alt_rule": r["band_alt_rule"],
                        "alt_coverage": r["band_alt_coverage_heldout"],
                        "alt_halfwidth": r["band_alt_halfwidth_heldout_median_um"], "bands": r["bands_heldout"],
                        "scale": r["distance_scale"], "rho": r["heldout_rho_median"],
                        "cpu_s": time.process_time() - t0})
    return out


def sim_one(args):
    family, seed = args[:2]
    shifted = args[2] if len(args) > 2 else True
    cols = SIMULATORS[family](seed, dt_s=SIM_DT_S, shift_at=SIM_SPLIT if shifted else None)
    truth = cols.pop("_truth")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, cols)
        log = load_drift_log(path)
    t0 = time.process_time()
    sel = DriftSelector(fit_fraction=SIM_SPLIT).fit(log)
    rep = sel.report(log)
    _, hold = sel.split(log)
    pred = sel.model_.predict(log, sel.cache_)
    base = sel.baseline_.predict(log, sel.cache_)
    cpu = time.process_time() - t0
    return [{"family": family, "seed": seed, "channel": ch, "model": r["model"], "before": r["rms_before_um"],
             "volcomp": r["rms_after_um"], "ols": r["rms_ols_um"],
             "true": _rms(truth["clean_um"][ch][hold] - pred[ch][hold]),
             "true_ols": _rms(truth["clean_um"][ch][hold] - base[ch][hold]), "noise": truth["noise_um"][ch],
             "coverage": r["band_coverage_heldout"], "halfwidth": r["band_halfwidth_heldout_median_um"],
             "alt_rule": r["band_alt_rule"], "alt_coverage": r["band_alt_coverage_heldout"],
             "alt_halfwidth": r["band_alt_halfwidth_heldout_median_um"], "bands": r["bands_heldout"],
             "scale": r["distance_scale"], "rho": r["heldout_rho_median"], "shifted": shifted, "cpu_s": cpu} for ch, r in rep.items()]


def render(real, sims, meta, out):
    L = ["# Drift models on a future that leaves the fit range (issue 29)", "",
         f"`python benchmarks/bench_drift_regime.py --seeds {meta['seeds']} --jobs {meta['jobs']} --no-shift`: "
         f"{meta['wall_s']:.0f} s wall (load average {meta['load']:.1f}, {meta['where']})"
         + ("; INTERRUPTED at the deadline: rendered from the parts that finished" if meta.get("interrupted") else "")
         + ".", ""]
    L += [rule_text(), ""]
    if real:
        L += ["## The real log (first 60 % of a 46 h machine-tool log, 15 s sampling)", "",
              "Held-out RMS (μm) of the MEASURED residual on the part after the fit; *OLS*: one least-squares "
              "fit on every temperature + speed on the same fitting rows; *before*: the displacement itself.", "",
              "| split (of the full log) | channel | chosen | s (distance scale) | held-out ρ median | before | "
              "**volcomp** | OLS | volcomp / OLS | band ± (μm, at ρ ≤ 1) | band ± held out (median μm) | "
              "band coverage held out | " + " | ".join(f"{b} band: ± held out (median μm), coverage" for b in _alt())
              + " |", "|" + "---|" * (12 + len(_alt()))]
        names = {0.6: "fit 0–36 % → judge 36–60 %", 0.8: "fit 0–48 % → judge 48–60 %"}
        for r in real:
            sc = r.get("scale")
            L.append(f"| {names[r['split']]} | {r['channel']} | {r['model']} | {'∞' if sc is None else f'{sc:g}'} | "
                     f"{r.get('rho', float('nan')):.2f} | {r['before']:.3g} | "
                     f"**{r['volcomp']:.3g}** | {r['ols']:.3g} | {r['volcomp'] / r['ols']:.2f} | {r['band']:.3g} | "
                     f"{r.get('halfwidth', float('nan')):.3g} | {r['coverage']:.2f} | "
                     + " | ".join(f"{_band(r, b, 'halfwidth_median_um'):.3g}, {_band(r, b, 'coverage'):.2f}"
                                  for b in _alt()) + " |")
        worse = [r for r in real if r["volcomp"] > r["ols"] * (1 + 1e-9)]
        L += ["", f"Channels × splits above OLS: {len(worse)} of {len(real)}"
              + (": " + "; ".join(f"{r['channel']} at {r['split']}" for r in worse) if worse else "")
              + f"; strictly below: {sum(r['volcomp'] < r['ols'] * (1 - 1e-9) for r in real)}; "
              f"ties (OLS chosen): {sum(r['model'] == 'ols' for r in real)}.", "",
              "Rolling-origin validation inside the fitting part (RMS μm, chosen / OLS): ranking folds (4 "
              "blocks after the first half), horizon folds (blocks as long, relative to training, as the "
              "held-out part), novelty folds (3 most novel of 8 blocks, left out):", "",
              "| split | channel | chosen | ranking | horizon | novelty |", "|---|---|---|---|---|---|"]
        for r in real:
            L.append(f"| {r['split']:.0%} of the part | {r['channel']} | {r['model']} | {r['cv']:.3g} / {r['cv_ols']:.3g} "
                     f"| {r['cv_h']:.3g} / {r['cv_h_ols']:.3g} | {r['cv_n']:.3g} / {r['cv_n_ols']:.3g} |")
        L += ["", f"CPU per fit+selection: {np.median([r['cpu_s'] for r in real]):.0f} s (median over splits).", ""]
    else:
        L += ["## The real log", "", f"not run: {REAL} is absent.", ""]
    shifted = [r for r in sims if r.get("shifted", True)]
    plain = [r for r in sims if not r.get("shifted", True)]
    if shifted:
        L += sim_section(shifted, meta, True)
    if plain:
        L += sim_section(plain, meta, False)
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L) + "\n")
    return L


def _alt():
    """The band rules reported beside the model's (``BAND_RULE``)."""
    return [b for b in BAND_RULES if b != BAND_RULE]


def _band(r, rule, key):
    """One band rule's held-out figure of a row (nan for rows saved before the rule existed)."""
    return (r.get("bands") or {}).get(rule, {}).get(key, float("nan"))


def band_summary(rows):
    """Held-out coverage of every band rule over ``rows``: median, cases in 90–98 %, at ≥ 90 %, median ± μm."""
    parts = []
    for b in BAND_RULES:
        cov = np.array([_band(r, b, "coverage") for r in rows])
        parts.append(f"{b}{' (the model’s)' if b == BAND_RULE else ''}: median {np.nanmedian(cov):.2f}, "
                     f"{int(((cov >= 0.9) & (cov <= 0.98)).sum())} of {len(rows)} in 90–98 %, "
                     f"{int((cov >= 0.9).sum())} at 90 % or more, median half-width "
                     f"{np.nanmedian([_band(r, b, 'halfwidth_median_um') for r in rows]):.3g} μm")
    return f"Band coverage held out over all {len(rows)} cases — " + "; ".join(parts) + "."


def rule_text():
    """The selection and band rules in force (from drift_models' constants), in words."""
    order = "the eligible one of largest mean log-gain over OLS"
    band = {"fold_residual": "the split-conformal 95 % quantile of |validation residual| on the horizon and novelty "
                             "folds, times max(1, ρ) at each sample",
            "rho_scaled": "the split-conformal 95 % quantile of |residual| / max(1, ρ_fold) on the horizon and "
                          "novelty folds, times max(1, ρ) at each sample",
            "rho_power": "q·max(1, ρ)^γ: for each γ of " + ", ".join(f"{g:g}" for g in BAND_GAMMAS) + " q is the "
                         "split-conformal 95 % quantile of |residual| / max(1, ρ)^γ on the horizon and novelty "
                         "folds; γ is the smallest that also covers 95 % of the fold rows outside the range "
                         "(ρ > 1) and of the farther half of them",
            "fold_flat": "the split-conformal 95 % quantile of |validation residual| on the horizon and novelty folds, "
                         "not grown with ρ"}
    return ("Selection rule (docs/explanation/drift.md): a candidate — a family, or a family shrunk toward OLS, "
            "predicting OLS + w0·g(ρ)·(candidate − OLS) per sample (w0 ∈ " + ", ".join(f"{w:g}" for w in SHRINK_WEIGHTS)
            + "; ρ = the distance of the "
            "sample's raw inputs from the fit data over the fit data's 99th-percentile distance; g = 1 for ρ ≤ 1, "
            "exp(−(ρ − 1)/s) beyond, s chosen on the novelty folds) — is eligible only when it is below OLS on the "
            "ranking folds AND beats OLS by more than one standard error on the horizon folds AND on the novelty "
            "folds (the most novel blocks of the fitting part by Mahalanobis distance of the standardised inputs, "
            "held out), by at least 5 % on average on each of those two sets, and loses to OLS by no more than 5 % "
            f"on any ranking, horizon or novelty fold; {order} is returned, else OLS itself (the variants were "
            "compared on development seeds 100–104 and inside the real log's fitting parts, "
            f"benchmarks/drift_dev_results.md). Band: {band[BAND_RULE]}; beside it the other band rules ("
            + "; ".join(f"{b}: {band[b]}" for b in _alt()) + "), measured, not the model's.")


def sim_section(sims, meta, shifted):
    L = []
    if shifted:
        L += [f"## Simulated logs with a later regime outside the fit range ({meta['seeds']} seeds per family)", "",
              f"Both families sampled every {SIM_DT_S:g} s; from {SIM_SPLIT:.0%} of the log on the spindle runs "
              f"{SHIFT_SPEED:g}× faster and the ambient is {SHIFT_AMBIENT_C:g} °C warmer (1 h ramp); fit on the first "
              f"{SIM_SPLIT:.0%}, judged on the rest. Ratio = volcomp / OLS held-out RMS of the measured residual "
              f"(median, worst over seeds); *true*: noise-free displacement − prediction (median), OLS's beside.", ""]
    else:
        L += [f"## The same simulated logs without a regime change ({len({(r['family'], r['seed']) for r in sims})} logs: "
              + ", ".join(f"{f} seeds {sorted({r['seed'] for r in sims if r['family'] == f})}"
                          for f in dict.fromkeys(r["family"] for r in sims)) + ")", "",
              f"As above but the later part runs as the fitting part did (no speed or ambient shift); fit on the first "
              f"{SIM_SPLIT:.0%}, judged on the rest (what `bench_drift.py` measured before issue 29; folded in here).", ""]
    L += ["| simulator | channel | before | **volcomp** | OLS | ratio median | ratio worst | seeds > OLS·1.05 | "
          "seeds < OLS | true volcomp / OLS | band coverage held out (median, min) | band ± held out (median μm) | "
          + " | ".join(f"{b} band: coverage (median, min), ± (median μm)" for b in _alt())
          + " | families chosen |", "|" + "---|" * (13 + len(_alt()))]
    bad, med_bad, med_ratio_bad = [], [], []
    for f in dict.fromkeys(r["family"] for r in sims):
        for ch in dict.fromkeys(r["channel"] for r in sims if r["family"] == f):
            c = [r for r in sims if r["family"] == f and r["channel"] == ch]
            ratio = [r["volcomp"] / r["ols"] for r in c]
            fams = {}
            for r in c:
                k = r["model"].split("[")[0].split("~")[0] + ("~ols" if "~ols" in r["model"] else "")
                fams[k] = fams.get(k, 0) + 1
            over = [r for r in c if r["volcomp"] > TOLERATED_LOSS * r["ols"]]
            bad += over
            if np.median([r["volcomp"] for r in c]) >= np.median([r["ols"] for r in c]):
                med_bad.append(f"{f} {ch}")
            if np.median(ratio) >= 1 - 1e-9:
                med_ratio_bad.append(f"{f} {ch} ({np.median(ratio):.3f})")
            L.append(f"| {f} | {ch} | {np.median([r['before'] for r in c]):.3g} | "
                     f"**{np.median([r['volcomp'] for r in c]):.3g}** | {np.median([r['ols'] for r in c]):.3g} | "
                     f"{np.median(ratio):.2f} | {max(ratio):.2f} | {len(over)} | {sum(x < 1 for x in ratio)}/{len(c)} | "
                     f"{np.median([r['true'] for r in c]):.3g} / {np.median([r['true_ols'] for r in c]):.3g} | "
                     f"{np.median([r['coverage'] for r in c]):.2f}, {min(r['coverage'] for r in c):.2f} | "
                     f"{np.median([r.get('halfwidth', float('nan')) for r in c]):.3g} | "
                     + "".join(f"{np.median([_band(r, b, 'coverage') for r in c]):.2f}, "
                               f"{min(_band(r, b, 'coverage') for r in c):.2f}, "
                               f"{np.median([_band(r, b, 'halfwidth_median_um') for r in c]):.3g} | " for b in _alt())
                     + f"{', '.join(f'{k} {v}' for k, v in sorted(fams.items()))} |")
    L += ["", f"Seed × channel cases worse than OLS by more than 5 %: {len(bad)} of {len(sims)}"
          + (" (" + "; ".join(f"{r['family']} seed {r['seed']} {r['channel']} {r['model']} "
                              f"{r['volcomp'] / r['ols']:.2f}×" for r in bad) + ")" if bad else "")
          + ". Channels whose median RMS is not below OLS's: " + ("; ".join(med_bad) if med_bad else "none")
          + "; whose median ratio is not below 1 (at least half the seeds tie or lose): "
          + ("; ".join(med_ratio_bad) if med_ratio_bad else "none") + ".",
          "", band_summary(sims),
          "", f"CPU per log: {np.median([r['cpu_s'] for r in sims]):.0f} s (median).", ""]
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--families", default="lumped,rod")
    ap.add_argument("--no-real", action="store_true")
    ap.add_argument("--no-sim", action="store_true")
    ap.add_argument("--no-shift", action="store_true", help="also the simulated logs without a regime change")
    ap.add_argument("--where", default="the shared 2-core machine")
    ap.add_argument("--out", default=str(Path(__file__).with_name("drift_regime_results.md")))
    ap.add_argument("--render-only", action="store_true", help="re-render the .md from the saved .json")
    ap.add_argument("--partial", default=None, help="append every finished part as a JSON line to this file")
    ap.add_argument("--from-partial", default=None,
                    help="render from a --partial file of an interrupted run (the sections say how many seeds ran)")
    a = ap.parse_args(argv)
    js = Path(a.out).with_suffix(".json")
    if a.render_only:
        saved = json.loads(js.read_text())
        print("\n".join(render(saved["real"], saved["sims"], saved["meta"], a.out)))
        return
    if a.from_partial:
        parts = [json.loads(line) for line in Path(a.from_partial).read_text().splitlines() if line.strip()]
        meta = next(x["meta"] for x in parts if "meta" in x)
        real = [r for x in parts for r in x.get("real", [])]
        sims = [r for x in parts for r in x.get("sims", [])]
        meta.update({"wall_s": parts[-1].get("t", 0.0), "interrupted": True})
        write_json(js, {"meta": meta, "real": real, "sims": sims})
        print("\n".join(render(real, sims, meta, a.out)))
        return
    t0 = time.perf_counter()

    def part(obj):
        if a.partial:
            with open(a.partial, "a", encoding="utf-8") as fh:
                fh.write(json.dumps({**obj, "t": time.perf_counter() - t0}) + "\n")
    part({"meta": {"seeds": a.seeds, "jobs": a.jobs, "load": os.getloadavg()[0], "where": a.where}})
    real = real_rows() if REAL.is_file() and not a.no_real else []
    part({"real": real})
    for r in real:
        print(f"real {r['split']} {r['channel']} {r['model']} {r['volcomp'] / r['ols']:.3f}× OLS, band coverage "
              f"{r['coverage']:.2f}", file=sys.stderr, flush=True)
    print(f"real log done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    tasks = [(f, s, True) for f in a.families.split(",") for s in range(a.seeds)] if not a.no_sim else []
    if a.no_shift and not a.no_sim:
        tasks += [(f, s, False) for f in a.families.split(",") for s in range(a.seeds)]
    sims = []
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            for r in ex.map(sim_one, tasks):
                sims += r
    else:
        for t in tasks:
            rows = sim_one(t)
            sims += rows
            part({"sims": rows})
            worst = max(rows, key=lambda r: r["volcomp"] / r["ols"])
            print(f"{t} done ({time.perf_counter() - t0:.0f} s): worst {worst['channel']} {worst['model']} "
                  f"{worst['volcomp'] / worst['ols']:.3f}× OLS", file=sys.stderr, flush=True)
    meta = {"seeds": a.seeds, "jobs": a.jobs, "wall_s": time.perf_counter() - t0, "load": os.getloadavg()[0],
            "where": a.where}
    write_json(js, {"meta": meta, "real": real, "sims": sims})
    print("\n".join(render(real, sims, meta, a.out)))


if __name__ == "__main__":
    main()
