"""Benchmark of the check-measurement diagnosis (issue 6) and of the drift-log modelling.

For seeds 0..N-1 (default 20) on the built-in grinder, model = the truth element set
(HTMField of truth.elements), 400 checks, noise σ = 1 μm, fit/held-out split 60/40 by seq:

* no effect: how many effects are reported (false positives);
* each simulator effect alone: is the top effect's kind/axis/element right, and the
  held-out RMS after / the RMS of the same pipeline on the same seed without the effect;
* two effects at once (reversal + worm): are both found;
* drift logs (two of six sensors active, lag 300 s, noise 0.5 μm): sensors, lag, RMS, ambiguity;
  none active (false selections); a sensor beside another (ambiguity flagged?).

``--drift-only`` regenerates only the drift section of the results file.

Writes benchmarks/diagnosis_results.md. Run: ``python benchmarks/bench_diagnosis.py [--seeds 20] [--drift-only]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from errormap.diagnosis.checks import CheckData
from errormap.diagnosis.drift import DriftLog, DriftModeller, simulate_drift_log
from errormap.diagnosis.pipeline import diagnose
from errormap.htm import HTMField
from errormap.io import atomic_write
from errormap.machine import load_machine
from errormap.simulator import random_truth

EXPECTED = {"thermal": ("thermal", "x", {"dx_x"}), "reversal": ("reversal", "z", {"dz_z"}),
            "pitch": ("periodic", "x", {"dx_x"}), "worm": ("harmonic", "a", {"ex_a"}),
            "interaction": ("interaction", "x*z", {"dx_x", "dx"})}
RATIO_MAX = 1.25


def run(machine, seed, effects):
    truth = random_truth(machine, seed, effects=effects)
    checks = CheckData.from_columns(truth.check_measurements(400, 1.0, seed + 1000))
    return diagnose(machine, HTMField(machine, truth.elements), checks).summary


DRIFT_HEADING = "## Drift logs"


def _log(cols):
    return DriftLog(cols["time_s"], {k[5:-2]: v for k, v in cols.items() if k.startswith("temp_")},
                    {k[:-3]: v for k, v in cols.items() if k.endswith("_um")}, cols["speed_rpm"])


def drift_lines(seeds):
    """Drift-log scenarios: two of six active; none active; s6 a second reading of s2's spot."""
    rows, null_sel, copy_rows = [], 0, []
    for s in seeds:
        c = simulate_drift_log(s)
        truth = c.pop("_truth")
        log = _log(c)
        rep = DriftModeller().fit(log).report(log)
        for ch, r in rep.items():
            lo, hi = r["lag_interval_s"]
            rows.append({"right": sorted(r["regressors"]) == sorted(truth[ch]), "amb": r["ambiguous"],
                         "lag": r["lag_s"], "cover": lo <= 300 <= hi, "before": r["rms_before_um"],
                         "after": r["rms_after_um"],
                         "ru": r["runner_up"]["delta_bic"] if r["runner_up"] else np.inf,
                         "r": max(abs(v["r"]) for v in r["closest_sensors"].values()), "seed": s, "ch": ch})
        c = simulate_drift_log(s, active=())
        c.pop("_truth")
        log = _log(c)
        null_sel += sum(bool(r["regressors"]) for r in DriftModeller().fit(log).report(log).values())
        c = simulate_drift_log(s, copies={"s6": "s2"})
        c.pop("_truth")
        log = _log(c)
        for ch, r in DriftModeller().fit(log).report(log).items():
            copy_rows.append((sorted(r["regressors"]) in (["s2", "s5"], ["s5", "s6"]), r["ambiguous"]))
    N = len(rows)
    wrong = [r for r in rows if not r["right"]]
    amb = [r for r in rows if r["amb"]]
    return [f"{DRIFT_HEADING} (six sensors, s2 and s5 active, lag 300 s, noise 0.5 μm, 6 h at 10 s, {len(seeds)} seeds × 2 channels)", "",
            "Simulator: three heat sources reach each sensor's spot through first-order lags; a sensor reads its "
            "spot + 0.01 °C noise; the displacement follows the spots' true temperatures (not the readings). "
            "Model: temperatures smoothed over 60 s, exhaustive subsets of ≤ 4 regressors × every lag at 10 s, BIC.", "",
            "- " f"Right sensors (exactly s2 and s5): **{N - len(wrong)}/{N}** channels; wrong and not flagged ambiguous: "
            f"**{sum(not r['amb'] for r in wrong)}**; flagged ambiguous: {len(amb)} "
            f"(of which right: {sum(r['right'] for r in amb)}).",
            "- " f"Lag within 20 s of 300 s: {sum(abs(r['lag'] - 300) <= 20 for r in rows)}/{N}; 95 % lag interval covers 300 s: "
            f"{sum(r['cover'] for r in rows)}/{N}.",
            "- " f"Held-out RMS (mean) {np.mean([r['before'] for r in rows]):.2f} → {np.mean([r['after'] for r in rows]):.3f} μm "
            f"(max after {max(r['after'] for r in rows):.3f} μm; noise 0.5 μm).",
            "- " f"Runner-up subset ΔBIC: min {min(r['ru'] for r in rows):.1f}, median {np.median([r['ru'] for r in rows]):.0f}; "
            f"the selected sensors' closest other sensor |r|: median {np.median([r['r'] for r in rows]):.4f}, "
            f"max {max(r['r'] for r in rows):.4f}.",
            "- Misses: " + (", ".join(f"seed {r['seed']} {r['ch']} (runner-up ΔBIC {r['ru']:.1f}, ambiguous {r['amb']})"
                                      for r in wrong) or "none") + ".", "",
            f"No active sensor (pure noise): channels with any regressor selected: **{null_sel}/{N}**.", "",
            f"s6 a second reading of s2's spot (genuinely ambiguous): s5 + one of s2/s6 selected on "
            f"{sum(a for a, _ in copy_rows)}/{N}; flagged ambiguous on **{sum(b for _, b in copy_rows)}/{N}**.", ""]


def checks_lines(m, seeds):
    base = {s: run(m, s, []) for s in seeds}
    fp = {s: len(base[s]["effects"]) for s in seeds}
    rows = []
    for eff, (kind, axis, els) in EXPECTED.items():
        ok, ratios, before, after, extra = 0, [], [], [], 0
        for s in seeds:
            r = run(m, s, [eff])
            top = r["effects"][0] if r["effects"] else None
            hit = top is not None and (top["kind"], top["axis"]) == (kind, axis) and top["element"] in els
            ok += hit
            extra += max(0, len(r["effects"]) - 1)
            ratios.append(r["rms_after_um"] / base[s]["rms_after_um"])
            before.append(r["rms_before_um"])
            after.append(r["rms_after_um"])
        rows.append((eff, f"{kind} / {axis} / {'|'.join(sorted(els))}", ok, len(seeds), np.mean(before), np.mean(after),
                     np.mean([base[s]["rms_after_um"] for s in seeds]), max(ratios), sum(x <= RATIO_MAX for x in ratios), extra))
    two_ok = 0
    for s in seeds:
        r = run(m, s, ["reversal", "worm"])
        f = {(e["kind"], e["axis"], e["element"]) for e in r["effects"]}
        two_ok += {("reversal", "z", "dz_z"), ("harmonic", "a", "ex_a")} <= f
    n = len(seeds)
    lines = ["# Diagnosis benchmark (issue 6)", "",
             f"Generated by `benchmarks/bench_diagnosis.py --seeds {n}` in SECS s. Residual: MEASURED "
             "(measurement − model prediction). Model: the truth element set; 400 checks, noise σ = 1 μm per axis, "
             "split 60/40 by seq (held-out part later in time). RMS/max of the residual vector norm on the held-out part.", "",
             "## False positives (no undeclared effect)", "",
             f"Effects reported over {n} seeds: **{sum(fp.values())}** (seeds with any: "
             f"{[s for s in seeds if fp[s]] or 'none'}).", "",
             "## One undeclared effect", "",
             "| simulator effect | expected kind / axis / element | top effect right | mean RMS before (μm) | mean RMS after (μm) "
             "| mean RMS without effect (μm) | max ratio after/without | seeds with ratio ≤ 1.25 | extra effects |",
             "|---|---|---|---|---|---|---|---|---|"]
    for eff, exp, ok, tot, b, a, w, mx, nr, extra in rows:
        lines.append(f"| {eff} | {exp} | {ok}/{tot} | {b:.3f} | {a:.3f} | {w:.3f} | {mx:.3f} | {nr}/{tot} | {extra} |")
    lines += ["", "## Two effects at once (reversal + worm)", "", f"Both found: **{two_ok}/{n}** seeds.", ""]
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default=str(Path(__file__).with_name("diagnosis_results.md")))
    ap.add_argument("--drift-only", action="store_true", help="regenerate only the drift section of --out")
    args = ap.parse_args(argv)
    m = load_machine()
    t0 = time.perf_counter()
    seeds = range(args.seeds)
    n = len(seeds)
    drift = drift_lines(seeds)
    if args.drift_only:
        old = Path(args.out).read_text(encoding="utf-8")
        head = old[:old.index(DRIFT_HEADING)].rstrip("\n").split("\n")
        secs = time.perf_counter() - t0
        head = [h for h in head if not h.startswith("Drift section regenerated")]
        head[3:3] = ["", f"Drift section regenerated by `benchmarks/bench_diagnosis.py --seeds {n} --drift-only` in "
                         f"{secs:.0f} s; the sections above are from the full run."]
        lines = head + [""] + drift
    else:
        lines = checks_lines(m, seeds) + drift
        secs = time.perf_counter() - t0
        lines[2] = lines[2].replace("SECS", f"{secs:.0f}")
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
