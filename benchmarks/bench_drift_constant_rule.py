"""The constant-offset fallback of the drift selection: a model ships only where it beats the constant on the folds.

The rule measured: a candidate (a family other than the two plain baselines) that passes every gate against OLS
ships only where, over every validation fold of the fitting part (ranking, horizon and novelty folds), its per-fold
log-gain over the constant offset d_i = ln(RMS_constant,i / RMS_candidate,i) has mean > k · sd(d)/√K (a paired
one-sided test, k standard errors); else the constant ships. Variants: the test only where the constant is the
plain fallback (its validation gain over OLS > 0: "-fallback"); OLS too must beat the constant that way ("+ols").

Judged, for each case and channel, by the held-out RMS of the MEASURED residual (μm, the last part of the log by
time, never seen by the selection) of the chosen model under today's rule and under each variant, beside OLS and
the constant (the fitting part's mean). Cases:

* ``real``: the shared real thermal log (``../shared/data/thermal-log/log_first60.csv``; skipped with a note where
  absent), fit on its first 60 % / 80 %, judged on the rest;
* ``offset``: offset-only simulated logs (an offset + a slow swing + white noise the temperatures do not drive; the
  test suite's ``tests/test_drift_constant.py`` log), seeds 0..N−1, and the same generator's linear logs (OLS's
  own model) beside;
* ``lumped`` / ``rod``: both families of ``errormap/diagnosis/drift_sim.py``, 60 s sampling, with and without the
  later regime change, seeds 0..N−1.

Run: ``python benchmarks/bench_drift_constant_rule.py --seeds 5 --offset-seeds 20 --json out.json`` (about 2 CPU min).
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from errormap.diagnosis.drift import DriftLog, load_drift_log  # noqa: E402
from errormap.diagnosis.drift_models import DriftSelector, band_of, candidate_name, default_families  # noqa: E402
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import write_csv  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
REAL_SPLITS = (0.6, 0.8)
SIM_DT_S = 60.0
SIM_SPLIT = 0.6
OFFSET_DT_S, OFFSET_ROWS, OFFSET_UM, OFFSET_NOISE_UM = 120.0, 900, 7.0, 0.3
T95 = 1.812   # one-sided 95 % t quantile, 10 degrees of freedom (11 folds)
RULES = {"today": None, "1se": (1.0, "always"), "t95": (T95, "always"), "1se+ols": (1.0, "ols"),
         "1se-fallback": (1.0, "fallback"), "t95-fallback": (T95, "fallback")}
PLAIN = ("ols", "constant")


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def offset_log(seed: int, linear: bool) -> DriftLog:
    """The test suite's simulated log: three wandering temperatures; one channel ``ch``, ``linear`` → 2·a − 1.5·b +
    noise, else an offset + a slow 0.3 μm swing + noise the temperatures do not drive."""
    rng = np.random.default_rng(seed)
    t = np.arange(OFFSET_ROWS) * OFFSET_DT_S
    temps = {s: 20.0 + np.cumsum(rng.normal(0.0, 0.05, OFFSET_ROWS)) for s in ("a", "b", "c")}
    if linear:
        d = 2.0 * (temps["a"] - 20.0) - 1.5 * (temps["b"] - 20.0) + rng.normal(0.0, OFFSET_NOISE_UM, OFFSET_ROWS)
    else:
        d = OFFSET_UM + 0.3 * np.sin(t / 7200.0) + rng.normal(0.0, OFFSET_NOISE_UM, OFFSET_ROWS)
    return DriftLog(t, temps, {"ch": d}, None, f"<offset {seed}>")


def paired_gain(stats_a: dict, stats_b: dict) -> tuple[float, float]:
    """(mean, se) over every fold of d_i = ln(RMS_b,i / RMS_a,i): a's per-fold log-gain over b (fold ratios to OLS)."""
    ra = np.concatenate([np.asarray(x, float) for x in stats_a["fold_ratios"]])
    rb = np.concatenate([np.asarray(x, float) for x in stats_b["fold_ratios"]])
    d = np.log(rb) - np.log(ra)
    return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d)))


def choose(sel, ch, rule) -> tuple:
    """The candidate key (family, hyper, w) channel ``ch`` ships under ``rule``, from the fitted selection's
    validation figures. None: the rule without the constant test (every gate against OLS and a mean log-gain above
    the constant's; else the constant where its mean log-gain over OLS is > 0, else OLS). ``(k, where)``: besides, a
    model ships only where its :func:`paired_gain` over the constant is > ``k`` SE, else the constant; ``where``
    "always"; "fallback": only where the constant is the plain fallback (its mean log-gain over OLS > 0); "ols": always,
    and OLS too ships only where it beats the constant that way."""
    cands = sel.candidates_[ch]
    const, ols = ("constant", "", 1.0), ("ols", "", 1.0)
    r_ols = cands[ols]["ranking"]
    floor = cands[const]["gain"]
    ok = [k for k in cands if k[0] != "ols" and sel.eligible(cands[k], cands[k]["gate"], k[2], r_ols, True)
          and (k == const or cands[k]["gain"] > floor)]
    refused = []
    if rule is not None and (rule[1] != "fallback" or floor > 0):
        refused = [k for k in ok if k != const and not (lambda m, s: m > rule[0] * s)(
            *paired_gain(cands[k], cands[const]))]
        ok = [k for k in ok if k not in refused]
    if ok:
        return max(ok, key=lambda k: cands[k]["gain"])
    if rule is not None and rule[1] == "ols":
        m, s = paired_gain(cands[ols], cands[const])
        return ols if m > rule[0] * s else const
    return const if floor > 0 or refused else ols


def names(k):
    return candidate_name(*k)


def held_out(sel, log, ch, key, rep) -> float:
    """Held-out MEASURED RMS (μm) of channel ``ch`` shipping candidate ``key`` (refitted on the fitting part)."""
    fit, hold = sel.split(log)
    if key[0] == "constant":
        return rep["rms_constant_um"]
    if key[0] == "ols":
        return rep["rms_ols_um"]
    if key == (*sel.chosen_[ch], sel.shrink_[ch]):
        return rep["rms_after_um"]
    s2 = copy.copy(sel)
    for name in ("chosen_", "shrink_", "scale_", "band_"):
        setattr(s2, name, dict(getattr(sel, name)))
    st = sel.candidates_[ch][key]
    s2.chosen_[ch], s2.shrink_[ch], s2.scale_[ch] = key[:2], key[2], st["scale"]
    s2.band_[ch] = band_of(st, sel.band_rule)
    fams = sel.families or default_families(sel.subset_kw)
    sets = s2._fold_sets(log, fit, sel.cache_)
    from errormap.diagnosis.drift_models import input_matrix
    model, _ = s2._final_models(log, fams, list(log.disp_um), fit, sel.cache_, input_matrix(log, fit, sel.cache_),
                                sets)
    pred = model.predict(log, sel.cache_)[ch]
    return _rms(log.disp_um[ch][hold] - pred[hold])


def case_rows(case: str, log: DriftLog, frac: float) -> list:
    t0 = time.process_time()
    sel = DriftSelector(fit_fraction=frac).fit(log)
    rep = sel.report(log)
    out = []
    for ch, r in rep.items():
        row = {"case": case, "channel": ch, "ols": r["rms_ols_um"], "constant": r["rms_constant_um"],
               "constant_gain": sel.candidates_[ch][("constant", "", 1.0)]["gain"]}
        shipped = (*sel.chosen_[ch], sel.shrink_[ch])
        assert shipped in {choose(sel, ch, rule) for rule in RULES.values()}, (case, ch, shipped)
        for name, rule in RULES.items():
            key = choose(sel, ch, rule)
            row[name] = held_out(sel, log, ch, key, r)
            row[f"{name}_model"] = names(key)
            if key[0] not in PLAIN:
                row[f"{name}_vs_constant"] = paired_gain(sel.candidates_[ch][key], sel.candidates_[ch][("constant", "", 1.0)])
        out.append(row)
    out[-1]["cpu_s"] = time.process_time() - t0
    return out


def all_rows(n_seeds: int, n_offset_seeds: int) -> list:
    rows = []
    if REAL.is_file():
        log = load_drift_log(REAL)
        for f in REAL_SPLITS:
            rows += case_rows(f"real fit {f:.0%}", log, f)
    else:
        print(f"note: {REAL} absent: the real log's rows are skipped", file=sys.stderr)
    for seed in range(n_offset_seeds):
        rows += case_rows(f"offset s{seed}", offset_log(seed, False), SIM_SPLIT)
        rows += case_rows(f"linear s{seed}", offset_log(seed, True), SIM_SPLIT)
    for fam in SIMULATORS:
        for shifted in (False, True):
            for seed in range(n_seeds):
                cols = SIMULATORS[fam](seed, dt_s=SIM_DT_S, shift_at=SIM_SPLIT if shifted else None)
                cols.pop("_truth")
                with tempfile.TemporaryDirectory() as d:   # the user's path: written, read as diagnose reads it
                    write_csv(Path(d) / "log.csv", cols)
                    log = load_drift_log(Path(d) / "log.csv")
                rows += case_rows(f"{fam}{' shift' if shifted else ''} s{seed}", log, SIM_SPLIT)
        print(f"{fam} done", file=sys.stderr)
    return rows


def summary(rows: list) -> list:
    """Markdown lines: per group (real, offset, linear, lumped, …) and rule, the geometric-mean held-out ratio to
    OLS and to the constant, the cases worse than the better plain baseline by > 5 %, the worst ratio, and the
    rows where a rule changed the choice."""
    groups = {}
    for r in rows:
        groups.setdefault(r["case"].rsplit(" s", 1)[0] if not r["case"].startswith("real") else "real", []).append(r)
    L = ["| cases | n | rule | geo-mean / OLS | geo-mean / constant | > 1.05× the better plain | worst / better plain |",
         "|---|---|---|---|---|---|---|"]
    for g, rs in groups.items():
        for name in RULES:
            v = np.array([r[name] for r in rs])
            o, c = np.array([r["ols"] for r in rs]), np.array([r["constant"] for r in rs])
            best = np.minimum(o, c)
            L.append(f"| {g} | {len(rs)} | {name} | {np.exp(np.mean(np.log(v / o))):.3f} | "
                     f"{np.exp(np.mean(np.log(v / c))):.3f} | {int(np.sum(v > 1.05 * best))} | {np.max(v / best):.2f} |")
    L += ["", "Changed choices (held-out RMS μm):", ""]
    for r in rows:
        if any(r[f"{n}_model"] != r["today_model"] for n in RULES):
            L.append(f"- {r['case']} {r['channel']}: OLS {r['ols']:.3f}, constant {r['constant']:.3f} (its validation "
                     f"gain over OLS {r['constant_gain']:+.3f}); " + "; ".join(
                f"{n} {r[f'{n}_model']} {r[n]:.3f}" for n in RULES))
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds of each simulator family")
    ap.add_argument("--offset-seeds", type=int, default=20, help="seeds of the offset-only and linear logs")
    ap.add_argument("--json", default=None, help="also write every row here")
    a = ap.parse_args(argv)
    rows = all_rows(a.seeds, a.offset_seeds)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    print("\n".join(summary(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
