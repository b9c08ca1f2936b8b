"""Drift-model benchmark (issue 14): volcomp's CV-chosen causal model against the OLS baseline.

The user's path on every seed: simulate a log (hidden truth kept aside) → write the CSV → load it
as `volcomp diagnose --drift` does (dropouts filled or inputs dropped) → DriftSelector (families
chosen by rolling-origin CV on the fitting part) → held-out evaluation on the last part.

Two independent simulator families (errormap/diagnosis/drift_sim.py): ``lumped`` (five-body
network, 18 sensors, 5 channels, 46 h at 15 s, like the real log) and ``rod`` (conducting column
with coolant and door, 20 sensors, 4 channels, 40 h at 20 s). Splits 60/40 and 80/20 by time.

Per channel: held-out RMS of the MEASURED residual (displacement − prediction) before (no
compensation), volcomp, OLS baseline; the TRUE residual (noise-free displacement − prediction);
and volcomp / noise floor (the measured residual cannot go below the channel's noise σ).
Medians over seeds; counts of seed×channel cases where volcomp is below OLS and below before.

Run: ``python benchmarks/bench_drift.py --seeds 10 --jobs 2`` → benchmarks/drift_results.md (+ .json).
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
from errormap.diagnosis.drift_models import DriftSelector, default_families, feature_matrix  # noqa: E402
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import atomic_write, write_csv, write_json  # noqa: E402

SPLITS = (0.6, 0.8)


def one(args):
    family, seed, kw = args
    cols = SIMULATORS[family](seed, **kw)
    truth = cols.pop("_truth")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, cols)
        log = load_drift_log(path)
    out = []
    for ff in SPLITS:
        t0 = time.perf_counter()
        sel = DriftSelector(fit_fraction=ff).fit(log)
        rep = sel.report(log)
        _, hold = sel.split(log)
        pred = sel.model_.predict(log, sel.cache_)
        fit = sel.split(log)[0]
        fams = {f.name: f for f in default_families()}
        for ch, r in rep.items():
            true_res = truth["clean_um"][ch][hold] - pred[ch][hold]
            # the round-1 rule in the same run: lowest ranking-fold RMS, no horizon gate
            first = r["best_ranked"]
            if first == r["model"]:
                ungated = r["rms_after_um"]
            else:
                cand, _, shrunk = first.partition("~ols(w=")       # a candidate shrunk toward OLS: blend
                w = float(shrunk.rstrip(")")) if shrunk else 1.0
                f, hy = (cand.split("[", 1) + [""])[:2]
                feats, a, b = fams[f].fit(log, [ch], fit, sel.cache_)[ch][hy.rstrip("]")]
                fo, ao, bo = fams["ols"].fit(log, [ch], fit, sel.cache_)[ch][""]
                p = w * (a + feature_matrix(log, feats, sel.cache_)[hold] @ b) + \
                    (1 - w) * (ao + feature_matrix(log, fo, sel.cache_)[hold] @ bo)
                res = log.disp_um[ch][hold] - p
                ungated = float(np.sqrt(np.mean(res**2)))
            out.append({"family": family, "seed": seed, "split": ff, "channel": ch, "model": r["model"],
                        "before": r["rms_before_um"], "volcomp": r["rms_after_um"], "ols": r["rms_ols_um"],
                        "true": float(np.sqrt(np.mean(true_res**2))), "noise": truth["noise_um"][ch],
                        "coverage": r["band_coverage_heldout"], "dropped": sorted(log.notes["dropped"]),
                        "ungated_model": first, "ungated": ungated, "refused_by_gate": r["refused_by_gate"],
                        "fit_s": time.perf_counter() - t0})
    return out


def table(rows, family, split):
    sub = [r for r in rows if r["family"] == family and r["split"] == split]
    chans = list(dict.fromkeys(r["channel"] for r in sub))
    seeds = sorted({r["seed"] for r in sub})
    head = ("| channel | before | volcomp | OLS baseline | volcomp / OLS (median, worst) | true residual | "
            "volcomp / noise σ | < OLS | < before | 95 % band coverage | families chosen |")
    lines = [head, "|" + "---|" * 11]
    for ch in chans:
        c = [r for r in sub if r["channel"] == ch]
        med = {k: float(np.median([r[k] for r in c])) for k in ("before", "volcomp", "ols", "true", "coverage")}
        ratio = [r["volcomp"] / r["ols"] for r in c]
        noise = [r["volcomp"] / r["noise"] for r in c]
        fams = {}
        for r in c:
            f = r["model"].split("[")[0]
            fams[f] = fams.get(f, 0) + 1
        lines.append(f"| {ch} | {med['before']:.3g} | **{med['volcomp']:.3g}** | {med['ols']:.3g} | "
                     f"{np.median(ratio):.2f}, {max(ratio):.2f} | {med['true']:.3g} | {np.median(noise):.2f} | "
                     f"{sum(x < 1 for x in ratio)}/{len(c)} | {sum(r['volcomp'] < r['before'] for r in c)}/{len(c)} | "
                     f"{med['coverage']:.2f} | {', '.join(f'{k} {v}' for k, v in sorted(fams.items()))} |")
    return lines, len(seeds)


def issue_table(rows, family):
    """The issue's form: per split, per channel 'before → volcomp (OLS)', medians over seeds."""
    sub = [r for r in rows if r["family"] == family]
    chans = list(dict.fromkeys(r["channel"] for r in sub))
    lines = ["| split | " + " | ".join(chans) + " |", "|---|" + "---|" * len(chans)]
    for sp in SPLITS:
        cells = []
        for ch in chans:
            c = [r for r in sub if r["split"] == sp and r["channel"] == ch]
            med = {k: float(np.median([r[k] for r in c])) for k in ("before", "volcomp", "ols")}
            cells.append(f"{med['before']:.3g} → **{med['volcomp']:.3g}** ({med['ols']:.3g})")
        lines.append(f"| fit {sp:.0%}: before → volcomp (plain OLS) | " + " | ".join(cells) + " |")
    return lines


def render(rows, meta, out):
    fams = list(dict.fromkeys(r["family"] for r in rows))
    seeds = meta["seeds"]
    lines = ["# Drift models: volcomp vs the OLS baseline (issue 14)", "",
             f"`python benchmarks/bench_drift.py --seeds {seeds} --jobs {meta['jobs']}`: {meta['logs']} logs × "
             f"{len(SPLITS)} splits in {meta['wall_s']:.0f} s wall (load average {meta['load']:.1f} on "
             f"{meta.get('where', 'the shared 2-core machine')}); median fit+selection {np.median([r['fit_s'] for r in rows]):.0f} s per log and split.",
             "", "", "",
             "Held-out RMS (μm) of the MEASURED residual (displacement − prediction) on the last part of each log, "
             f"medians over seeds 0..{seeds - 1}. *before*: the displacement itself; *OLS baseline*: one "
             "least-squares regression on every temperature + speed_rpm fitted on the same first part; *true "
             "residual*: noise-free displacement − volcomp's prediction; *volcomp / noise σ*: the measured "
             "residual over the channel's measurement noise (1.0 is the floor); *< OLS*, *< before*: seed count "
             "where volcomp's held-out RMS is below (a channel where CV chose OLS ties it: not counted as below). "
             "Coverage: fraction of held-out samples inside the 95 % band.", ""]
    desc = {"lumped": "lumped five-body network, 18 sensors (3 far from heat, 1 air), 46 h at 15 s",
            "rod": "conducting column + coolant + door (independent family), 20 sensors, 40 h at 20 s"}
    total, wins_ols, wins_before, ties = 0, 0, 0, 0
    for f in fams:
        lines += [f"## {f} ({desc.get(f, f)}): medians, issue's form", ""] + issue_table(rows, f) + [""]
    for f in fams:
        for sp in SPLITS:
            tl, ns = table(rows, f, sp)
            lines += [f"## {f}: fit {sp:.0%} / held out {1 - sp:.0%} ({ns} seeds)", ""] + tl + [""]
            sub = [r for r in rows if r["family"] == f and r["split"] == sp]
            total += len(sub)
            wins_ols += sum(r["volcomp"] < r["ols"] for r in sub)
            ties += sum(r["model"] == "ols" for r in sub)
            wins_before += sum(r["volcomp"] < r["before"] for r in sub)
    worst = sorted((r for r in rows if r["volcomp"] > r["ols"]), key=lambda r: -r["volcomp"] / r["ols"])[:3]
    lines[4] = (f"**Overall: volcomp below the OLS baseline on {wins_ols}/{total} seed×channel×split cases "
                f"({ties} ties where CV chose OLS itself; {total - wins_ols - ties} losses, all on 60/40 splits "
                if all(r["split"] == 0.6 for r in rows if r["volcomp"] > r["ols"]) else
                f"**Overall: volcomp below the OLS baseline on {wins_ols}/{total} seed×channel×split cases "
                f"({ties} ties where CV chose OLS itself; {total - wins_ols - ties} losses ")
    lines[4] += (f"— worst: " + "; ".join(f"{r['family']} seed {r['seed']} {r['channel']} {r['model']} "
                                         f"{r['volcomp']:.3g} vs {r['ols']:.3g} μm" for r in worst)
                 + f"), below before on {wins_before}/{total}.**")
    rule = ["## Selection rule: horizon gate vs the round-1 rule (same run, same logs)", "",
            "*round-1 rule*: the candidate with the lowest RMS on the ranking folds (short validation blocks "
            "after the first half of the fitting part). *volcomp (gated)*: the best-ranked candidate that also "
            "beats OLS by more than one standard error of the fold-to-fold scatter on the horizon folds "
            "(validation blocks as long, relative to their training, as the held-out part is to the fitting "
            "part), else OLS. Counts of seed×channel cases on the held-out part; ratio = held-out RMS / OLS's.", "",
            "| simulator | split | cases | round-1: < OLS | round-1: > OLS | round-1: worst ratio | "
            "gated: < OLS | gated: = OLS (chose OLS) | gated: > OLS | gated: worst ratio | geometric-mean ratio "
            "round-1 → gated |", "|" + "---|" * 11]
    for f in fams:
        for sp in SPLITS:
            sub = [r for r in rows if r["family"] == f and r["split"] == sp]
            r1 = [r["ungated"] / r["ols"] for r in sub]
            r2 = [r["volcomp"] / r["ols"] for r in sub]
            rule.append(f"| {f} | {sp:.0%}/{1 - sp:.0%} | {len(sub)} | {sum(x < 1 for x in r1)} | "
                        f"{sum(x > 1 for x in r1)} | {max(r1):.2f} | {sum(x < 1 for x in r2)} | "
                        f"{sum(r['model'] == 'ols' for r in sub)} | {sum(x > 1 for x in r2)} | {max(r2):.2f} | "
                        f"{np.exp(np.mean(np.log(r1))):.3f} → {np.exp(np.mean(np.log(r2))):.3f} |")
    lines[6:6] = rule + [""]
    short = []
    for f in fams:
        for sp in SPLITS:
            for ch in dict.fromkeys(r["channel"] for r in rows if r["family"] == f):
                c = [r for r in rows if r["family"] == f and r["split"] == sp and r["channel"] == ch]
                if np.median([r["volcomp"] for r in c]) >= np.median([r["ols"] for r in c]):
                    short.append(f"{f} {ch} at fit {sp:.0%}")
    losses = sorted((r for r in rows if r["volcomp"] > r["ols"]), key=lambda r: -r["volcomp"] / r["ols"])
    lines += ["## Where the target is missed", "",
              "The issue's target is every channel below the OLS baseline. The gate keeps OLS wherever no "
              "candidate is clearly better over the deployment's horizon (counted as ties, not as wins), and it "
              f"cannot foresee every held-out part: {len(losses)} seed×channel×split cases remain above OLS"
              + (" (" + "; ".join(f"{r['family']} seed {r['seed']} {r['channel']} fit {r['split']:.0%} {r['model']} "
                                  f"{r['volcomp'] / r['ols']:.2f}×" for r in losses) + ")" if losses else "")
              + ". Channels whose median over seeds is not below OLS: "
              + ("; ".join(short) if short else "none") + ".", ""]
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--families", default="lumped,rod")
    ap.add_argument("--out", default=str(Path(__file__).with_name("drift_results.md")))
    ap.add_argument("--where", default="the shared 2-core machine", help="machine description for the report")
    ap.add_argument("--render-only", action="store_true", help="re-render the .md from the saved .json")
    a = ap.parse_args(argv)
    js = Path(a.out).with_suffix(".json")
    if a.render_only:
        saved = json.loads(js.read_text())
        print("\n".join(render(saved["rows"], saved["meta"], a.out)))
        return
    fams = a.families.split(",")
    tasks = [(f, s, {}) for f in fams for s in range(a.seeds)]
    t0 = time.perf_counter()
    rows = []
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            for r in ex.map(one, tasks):
                rows += r
    else:
        for t in tasks:
            rows += one(t)
    meta = {"seeds": a.seeds, "jobs": a.jobs, "logs": len(tasks), "wall_s": time.perf_counter() - t0,
            "load": os.getloadavg()[0], "where": a.where}
    write_json(js, {"meta": meta, "rows": rows})
    print("\n".join(render(rows, meta, a.out)))


if __name__ == "__main__":
    main()
