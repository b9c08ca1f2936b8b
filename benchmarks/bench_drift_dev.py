"""Development seeds for the drift selection rule (issue 29): the rule is decided here, judged by bench_drift_regime.

The simulated logs of ``bench_drift_regime.py`` (both simulator families, the regime change from 60 % on) with
seeds DISJOINT from the benchmark's (default 100–109; the benchmark runs 0–9), fitted with
:class:`~errormap.diagnosis.drift_models.DriftSelector` under named rule variants, judged on the last 40 %:
held-out RMS of the MEASURED residual beside OLS, band coverage and median half-width. A rule change is
kept only when it helps here; its effect on the benchmark's seeds is then reported by bench_drift_regime.

Run: ``python benchmarks/bench_drift_dev.py --candidates cand.jsonl --seeds 100-104 [--no-shift]`` (every
candidate's validation statistics, held-out RMS and held-out coverage of every band rule, one JSON line per log),
``--candidates real.jsonl --real F [--upto U]`` (the real log: fitted on F of its first U — ``--upto`` = F gives
the pseudo-future INSIDE the benchmark's fitting part, on which a rule may be decided), then ``--rules cand.jsonl
--no-shift-rules … --nested-candidates … --real-candidates … [--judge-candidates …]`` →
benchmarks/drift_dev_results.md (the rule variants and the band rules compared offline on the same candidates;
with ``--with-families`` on the dumps, also the default rule with and without each measured non-default family); ``--variants feature,raw`` runs whole selections per variant
(``--partial FILE`` appends every finished log as a JSON line). ``--<name>-round FILE [--<name>-judge]``: whole
selections per variant of a round of ``WHOLE_SELECTION_ROUNDS`` on the development logs and the real fitting parts (with
``--<name>-judge``: the real pseudo-futures and the benchmark's seeds 0–9).
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
from errormap.diagnosis.drift_models import SHRINK_WEIGHTS, DriftSelector  # noqa: E402
from errormap.diagnosis.drift_sim import SIMULATORS  # noqa: E402
from errormap.io import atomic_write, write_csv, write_json  # noqa: E402

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "thermal-log" / "log_first60.csv"
SIM_SPLIT = 0.6
SIM_DT_S = 60.0
TOLERATED_LOSS = 1.05     # the bound: no channel worse than OLS by more than 5 % in any seed
VARIANTS = {"feature": {"feature_distance": True, "ranking_fold_loss": False},  # ρ = max(raw, the candidate's features)
            "raw": {"feature_distance": False, "ranking_fold_loss": False},     # ρ on the raw inputs (the rule before)
            "feature_rank": {"feature_distance": True, "ranking_fold_loss": True}}  # + the per-fold loss bound on
#                                                                                   the ranking folds (the default)


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def simulated_log(family, seed, shift=True):
    """The development log of one simulator family and seed (regime change at ``SIM_SPLIT`` when ``shift``), its
    truth dropped, written as a drift-log file and read back the way the command reads one."""
    cols = SIMULATORS[family](seed, dt_s=SIM_DT_S, shift_at=SIM_SPLIT if shift else None)
    cols.pop("_truth")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.csv"
        write_csv(path, cols)
        return load_drift_log(path)


def selected_report(log, fit_fraction, settings):
    """(the selector's per-channel report, CPU s of the selection and the report) for ``DriftSelector(**settings)``."""
    t0 = time.process_time()
    rep = DriftSelector(fit_fraction=fit_fraction, **settings).fit(log).report(log)
    return rep, time.process_time() - t0


def one(family, seed, variant):
    rep, cpu = selected_report(simulated_log(family, seed), SIM_SPLIT, VARIANTS[variant])
    return [{"family": family, "seed": seed, "variant": variant, "channel": ch, "model": r["model"],
             "volcomp": r["rms_after_um"], "ols": r["rms_ols_um"], "coverage": r["band_coverage_heldout"],
             "halfwidth": r["band_halfwidth_heldout_median_um"], "cpu_s": cpu} for ch, r in rep.items()]


def candidates(family, seed, shift=True, extra=False, weights=None):
    """Every candidate of every channel on one development log: its validation statistics (the selector's
    ``candidates_``) and its HELD-OUT RMS after refitting on the whole fitting part, predicted as the model would
    (OLS + w·g(ρ)·(candidate − OLS), ρ = max(raw inputs, its own features) from the fit rows), OLS's beside:
    the data on which rule variants are compared offline (``--rules``)."""
    log = simulated_log(family, seed, shift)
    return candidates_of(log, SIM_SPLIT, family, seed, extra, weights)


def candidates_of(log, fit_fraction, family, seed, extra=False, weights=None):
    """:func:`candidates` on a loaded ``log`` fitted on its first ``fit_fraction`` (rows tagged family, seed);
    ``extra``: the measured, non-default families (``drift_models.measured_families``) are candidates too;
    ``weights``: the blend weights w of the candidates (default: the selector's ``SHRINK_WEIGHTS``)."""
    from errormap.diagnosis.drift_models import (BAND_RULES, band_of, default_families, distance_weight,
                                                 feature_matrix, input_matrix, measured_families, relative_distance)
    families = default_families() + (measured_families() if extra else [])
    kw = {} if weights is None else {"shrink_weights": tuple(weights)}
    sel = DriftSelector(fit_fraction=fit_fraction, families=families, **kw).fit(log)
    fit, hold = sel.split(log)
    cache = sel.cache_
    n = len(log.time_s)
    chans = list(log.disp_um)
    final = {}
    for fam in families:
        try:
            final[fam.name] = fam.fit(log, chans, fit, cache)
        except ValueError:
            pass
    U = input_matrix(log, np.arange(n), cache)
    raw = relative_distance(U[fit], U)
    out = []
    for ch in chans:
        y = log.disp_um[ch][hold]
        fo, ao, bo = final["ols"][ch][""]
        ols = ao + feature_matrix(log, fo, cache) @ np.asarray(bo)
        r_ols = _rms(y - ols[hold])
        for (f, hy, w), st in sel.candidates_[ch].items():
            if f not in final or hy not in final[f].get(ch, {}):
                continue
            feats, a, b = final[f][ch][hy]
            F = feature_matrix(log, feats, cache)
            cand = a + F @ np.asarray(b)
            rho = np.maximum(raw, relative_distance(F[fit], F)) if feats and sel.feature_distance else raw
            pred = ols + w * distance_weight(rho, st["scale"]) * (cand - ols)
            g = st["gate"]
            err = np.abs(y - pred[hold])
            grow = np.maximum(1.0, rho[hold])
            gp = band_of(st, "rho_power")[1]
            bands = {b: band_of(st, b)[0] * grow ** band_of(st, b)[1] for b in BAND_RULES}
            out.append({"family": family, "seed": seed, "channel": ch, "cand": f, "hyper": hy, "w": w,
                        "ranking": st["ranking"], "horizon": st["horizon"], "novelty": st["novelty"],
                        "scale": None if not np.isfinite(st["scale"]) else st["scale"],
                        "worst_fold": st["worst_fold"], "gain": st["gain"], "fold_rho": st["fold_rho"],
                        "fold_ratios": st["fold_ratios"], "fold_rho_each": st["fold_rho_each"],
                        "band_gamma": gp,
                        "band_cover": {k: float(np.mean(err <= b)) for k, b in bands.items()},
                        "band_half": {k: float(np.median(b)) for k, b in bands.items()}, "gate_h": [bool(g[0][0]), g[0][1], g[0][2]],
                        "gate_n": [bool(g[1][0]), g[1][1], g[1][2]],
                        "heldout": _rms(y - pred[hold]), "heldout_ols": r_ols,
                        "heldout_rho_median": float(np.median(rho[hold])),
                        "chosen": (f, hy, w) == (*sel.chosen_[ch], sel.shrink_[ch])})
    return out


def head_of(log, fraction):
    """The first ``fraction`` of ``log``'s rows as a log (every column cut; the rest is never seen)."""
    import dataclasses
    n = int(round(fraction * len(log.time_s)))
    cut = {k: v[:n] for k, v in log.temps_c.items()}
    return dataclasses.replace(log, time_s=log.time_s[:n], temps_c=cut,
                               disp_um={k: v[:n] for k, v in log.disp_um.items()},
                               speed_rpm=None if log.speed_rpm is None else log.speed_rpm[:n],
                               path=f"{log.path}[:{fraction:g}]")


SHRINK_WEIGHTS_COARSE = (1.0, 0.75, 0.5, 0.25)   # the blend grid before steps of 1/8 (docs/decisions/006)
LCB_LEVEL = 0.95   # one-sided level of the lower confidence bound on the fold log-gains ("lcb" order)


def fold_gain_score(stats: dict, order: str) -> float:
    """The number by which an eligible candidate is ranked (larger is better) under ``order``, from its validation
    statistics (``DriftSelector.candidates_`` values: ``gain``, ``fold_ratios`` = (ranking, horizon, novelty) RMS
    ratios to OLS per fold, ``fold_rho_each`` = the folds' median ρ). The library ranks by ``mean_gain`` only; the
    other orders were measured here and refused (docs/decisions/005, 006). d_i = −ln(ratio_i) on the horizon and
    novelty folds: ``worst_fold`` −ln of the worst ratio over every fold; ``lcb`` mean(d) − t·sd(d)/√K;
    ``median_fold`` median d; ``rho_weighted`` mean d weighted by each fold's median ρ; ``trimmed_fold`` mean d
    without the largest."""
    if order == "mean_gain":
        return float(stats["gain"])
    fr = stats["fold_ratios"]
    if order == "worst_fold":
        return -float(np.log(max(max(x) for x in fr)))
    d = -np.log(np.asarray(list(fr[1]) + list(fr[2]), float))
    if order == "median_fold":
        return float(np.median(d))
    if order == "rho_weighted":
        w = np.maximum(np.asarray(list(stats["fold_rho_each"][1]) + list(stats["fold_rho_each"][2]), float), 1e-12)
        return float(np.sum(w * d) / np.sum(w))
    if order == "trimmed_fold":
        return float(np.sort(d)[:-1].mean()) if len(d) > 1 else float(d.mean()) if len(d) else 0.0
    if order == "lcb":
        from scipy.stats import t as student_t
        k = len(d)
        if k < 2:
            return float(d.mean()) if k else 0.0
        return float(d.mean() - student_t.ppf(LCB_LEVEL, k - 1) * d.std(ddof=1) / np.sqrt(k))
    raise ValueError(f"unknown order {order!r}")


LN_MIN_GAIN = float(np.log(1.05))
# rule variants compared offline on the same candidates (``--rules``): (weights allowed, per-fold loss bound,
# order among the eligible (fold_gain_score)[, worst-fold ratio under which w above w_max is allowed])
RULES = {"mean gain (the default)": (1.0, 1.05, "mean_gain"),
         "worst fold, w ≤ 0.5 unless every fold ≤ 0.5× OLS": (0.5, 1.05, "worst_fold", 0.5),
         "worst fold, w ≤ 1": (1.0, 1.05, "worst_fold"),
         "lower confidence bound (95 %, t over the horizon + novelty folds; must be > 0)": (1.0, 1.05, "lcb"),
         "median fold (horizon + novelty)": (1.0, 1.05, "median_fold"),
         "ρ-weighted fold gain (horizon + novelty)": (1.0, 1.05, "rho_weighted"),
         "mean gain, gates at 0.5 SE instead of 1": (1.0, 1.05, "mean_gain", 0.0, 0.5),
         "lower confidence bound, gates at 0.5 SE instead of 1": (1.0, 1.05, "lcb", 0.0, 0.5),
         "mean fold gain without the best fold (horizon + novelty; must be ≥ 5 %)": (1.0, 1.05, "trimmed_fold")}


def apply_rule(cands, w_max, loss, order, confident=0.0, k_se=1.0):
    """(held-out ratio to OLS, candidate name, the candidate's row) of what a rule returns among ``cands`` (one
    channel of one log); the gates are DriftSelector's."""
    ols = next(c for c in cands if c["cand"] == "ols")

    def eligible(c):
        worst = max(max(x) for x in c["fold_ratios"])
        return (c["cand"] != "ols" and (c["w"] <= w_max or worst <= confident) and c["ranking"] < ols["ranking"]
                and c["gate_h"][1] > k_se * c["gate_h"][2] and c["gate_n"][1] > k_se * c["gate_n"][2]
                and c["gate_h"][1] >= LN_MIN_GAIN
                and c["gate_n"][1] >= LN_MIN_GAIN and worst <= loss
                and (order != "lcb" or fold_gain_score(c, "lcb") > 0)
                and (order != "trimmed_fold" or fold_gain_score(c, "trimmed_fold") >= LN_MIN_GAIN))
    ok = [c for c in cands if eligible(c)]
    if not ok:
        return 1.0, "ols", ols
    best = max(ok, key=lambda c: (fold_gain_score(c, order), c["gain"]))
    w = "" if best["w"] == 1.0 else f"~ols(w={best['w']:g})"
    return best["heldout"] / best["heldout_ols"], f"{best['cand']}{w}", best


def _group(rows):
    by = {}
    for r in rows:
        by.setdefault((r["family"], r["seed"], r["channel"]), []).append(r)
    return by


from errormap.diagnosis.drift_models import BAND_RULES  # noqa: E402


# families measured in issue 29's third round: each is compared with the candidates of the families before it
# (the default rule applied with and without it); the rule tables use the default families' candidates only
FAMILIES_TRIED = ("gradient", "modes", "greybox_modes", "ols_stable_lag")   # drift_models.measured_families()


def render_families(sets):
    """Markdown lines: the default rule on the candidates of the earlier families, then with each family of
    ``FAMILIES_TRIED`` added (and all of them): per data set, the summary and every case whose choice changed."""
    rule = next(r for r in RULES.values() if r[2] == _default_selection())
    present = sorted({r["cand"] for rows in sets.values() for r in rows} & set(FAMILIES_TRIED))
    if not present:
        return []
    variants = {"before (the earlier families)": set()}
    variants.update({f"+ {f}": {f} for f in present})
    variants["+ all of them"] = set(present)
    L = ["## Families of issue 29's third round (the default rule, with and without each)", "",
         "Every log's candidates dumped with `--with-families` (`--candidates FILE --seeds 100-104 --with-families`, "
         "the same with `--seeds 100-102 --no-shift`, `--real 0.6 --upto 0.6`, `--real 0.8 --upto 0.8`, `--real 0.6`, "
         "`--real 0.8`, and `--seeds 0-9` for the benchmark's own logs), then `--rules … --judge-candidates FILE`; the "
         "rule tables above use the default families' candidates only. "
         "Each variant applies the default rule to the candidates of the earlier families plus the named ones (the "
         "rule is per candidate against OLS, so adding a family can only add eligible candidates). *sim*: cases > "
         "OLS·1.05, worst ratio, cases < OLS, geometric-mean ratio; *real*: cases above OLS, below, geometric-mean "
         "ratio.", "",
         "| families | " + " | ".join(t for t, r in sets.items() if r) + " |", "|---|" + "---|" * sum(bool(r) for r in sets.values())]
    changed = []
    for name, add in variants.items():
        cells = []
        for t, rows in sets.items():
            if not rows:
                continue
            by = _group([r for r in rows if r["cand"] not in FAMILIES_TRIED or r["cand"] in add])
            base = _group([r for r in rows if r["cand"] not in FAMILIES_TRIED])
            res = {k: apply_rule(c, *rule)[:2] for k, c in by.items()}
            v = np.array([x for x, _ in res.values()])
            gm = float(np.exp(np.mean(np.log(v))))
            if t.startswith("real"):
                cells.append(f"{int((v > 1 + 1e-9).sum())} above, {int((v < 1 - 1e-9).sum())} below, {gm:.3f}")
            else:
                cells.append(f"{int((v > TOLERATED_LOSS).sum())}, {v.max():.3f}, {int((v < 1 - 1e-9).sum())}, {gm:.3f}")
            if add:
                for k in sorted(res):
                    x0, c0 = apply_rule(base[k], *rule)[:2]
                    if res[k][1] != c0:
                        where = f"{_split_name(t, k[1])}, {k[2]}" if t.startswith("real") else f"{k[0]} s{k[1]} {k[2]}"
                        changed.append(f"* {name}, {t}: {where}: {c0} {x0:.3f} → {res[k][1]} {res[k][0]:.3f}")
        L.append(f"| {name} | " + " | ".join(cells) + " |")
    L += ["", "Cases whose choice changed (held-out ratio to OLS before → after):", ""] + (changed or ["* none"]) + [""]
    return L


# blend grids compared in issue 29's fourth round (the default rule on the candidates whose weight w is in the grid;
# the decision rule, written before the dumps were read, is in docs/explanation/drift.md)
GRIDS = {"A: the grid before (1, 0.75, 0.5, 0.25)": SHRINK_WEIGHTS_COARSE,
         "B: A + 0.125": SHRINK_WEIGHTS_COARSE + (0.125,),
         "C: steps of 1/8 (the default since)": SHRINK_WEIGHTS}
GRID_FILES = {"dev.jsonl": "development seeds 100–104, regime change from 60 % (decided on)",
              "devns.jsonl": "development seeds 100–102, no regime change (decided on)",
              "nested.jsonl": "real log, pseudo-future inside the fitting part (decided on)",
              "pf.jsonl": "real log, the benchmark's pseudo-future (judged, not decided on)",
              "judge.jsonl": "the benchmark's seeds 0–9, regime change (judged, not decided on)",
              "judgens.jsonl": "the benchmark's seeds 0–9, no regime change (judged, not decided on)"}


def render_grids(folder):
    """Markdown lines: the default rule applied to the candidates of each blend grid of ``GRIDS`` (dumped with
    ``--weights fine`` into ``folder``/``GRID_FILES``): per data set the summary, per real case the ratio, and every
    case whose choice differs from grid A."""
    rule = next(r for r in RULES.values() if r[2] == _default_selection())
    L = ["## Blend grids toward OLS (issue 29, fourth round)", "",
         "Candidates dumped with `--weights fine` (every family blended with OLS at w = 1, 0.875, …, 0.125: "
         "`--candidates DIR/dev.jsonl --seeds 100-104`, `DIR/devns.jsonl --seeds 100-102 --no-shift`, "
         "`DIR/nested.jsonl --real 0.6 --upto 0.6` and `--real 0.8 --upto 0.8`, `DIR/pf.jsonl --real 0.6` and "
         "`--real 0.8`; optionally `DIR/judge.jsonl --seeds 0-9`, `DIR/judgens.jsonl --seeds 0-9 --no-shift`), then "
         "`--rules … --grid-candidates DIR` (the sets present: " + ", ".join(
             t for f, t in GRID_FILES.items() if (Path(folder) / f).exists()) + "). Each grid: the default rule (largest mean gain, every gate) on the candidates whose "
         "w is in the grid (a candidate's statistics do not depend on the other weights, so grid A reproduces the "
         "rule before this round, and the tables above, computed on candidates of grid A). *sim*: cases > OLS·1.05, worst ratio, cases < OLS, geometric-mean ratio, channels whose median "
         "ratio ≥ 1; *real*: the held-out RMS ratio to OLS of the MEASURED residual per case.", ""]
    changed = []
    for fname, title in GRID_FILES.items():
        path = Path(folder) / fname
        if not path.exists():
            continue
        rows = [r for line in path.read_text().splitlines() if line.strip() for r in json.loads(line)]
        grouped = {g: _group([r for r in rows if r["w"] in ws]) for g, ws in GRIDS.items()}
        res = {g: {k: apply_rule(c, *rule)[:2] for k, c in by.items()} for g, by in grouped.items()}
        first = next(iter(GRIDS))
        if rows[0]["family"] == "real":
            keys = sorted(res[first])
            L += [f"### {title}", "", "| grid | " + " | ".join(f"{_split_name(title, s)}, {ch}" for _, s, ch in keys)
                  + " | above OLS | below | geometric mean |", "|---|" + "---|" * (len(keys) + 3)]
            for g, r in res.items():
                v = np.array([r[k][0] for k in keys])
                L.append(f"| {g} | " + " | ".join(f"{r[k][0]:.3f} ({r[k][1]})" for k in keys)
                         + f" | {int((v > 1 + 5e-4).sum())} | {int((v < 1 - 5e-4).sum())} | "
                           f"{np.exp(np.mean(np.log(v))):.3f} |")
        else:
            n_logs = len({(k[0], k[1]) for k in res[first]})
            L += [f"### {title} ({n_logs} logs, {len(res[first])} channel cases)", "",
                  "| grid | > OLS·1.05 | worst ratio | < OLS | geometric mean | median ratio per channel |",
                  "|---|---|---|---|---|---|"]
            for g, r in res.items():
                v = np.array([x for x, _ in r.values()])
                med = {}
                for (f, _, ch), (x, _) in sorted(r.items()):
                    med.setdefault(f"{f} {ch}", []).append(x)
                L.append(f"| {g} | {int((v > TOLERATED_LOSS).sum())} | {v.max():.3f} | {int((v < 1 - 5e-4).sum())} | "
                         f"{np.exp(np.mean(np.log(v))):.3f} | "
                         + ", ".join(f"{c} {np.median(x):.2f}" for c, x in med.items()) + " |")
            for g, r in res.items():
                bad = sorted(((x, k, c) for k, (x, c) in r.items() if x > TOLERATED_LOSS), reverse=True)
                if bad:
                    L.append(f"\n* {g}, above OLS·1.05: " + "; ".join(f"{k[0]} s{k[1]} {k[2]} {c} {x:.3f}×"
                                                                       for x, k, c in bad))
        L.append("")
        for g, r in res.items():
            for k in sorted(r):
                if g != first and r[k][1] != res[first][k][1]:
                    where = f"{_split_name(title, k[1])}, {k[2]}" if k[0] == "real" else f"{k[0]} s{k[1]} {k[2]}"
                    changed.append(f"* {g}, {title}: {where}: {res[first][k][1]} {res[first][k][0]:.3f} → "
                                   f"{r[k][1]} {r[k][0]:.3f}")
    L += ["Cases whose choice differs from grid A (held-out ratio to OLS, A → the grid):", ""] + (changed or ["* none"])
    return L + [""]


def render_rules(sets, out, grid_folder=None):
    """``sets``: {title: candidate rows}; titles starting "real" are the real log (one column per case), the others
    simulated logs (summary per rule); ``grid_folder``: the blend-grid comparison (:func:`render_grids`) too."""
    from errormap.diagnosis.drift_models import default_families
    fam_lines = render_families(sets)
    names = {f.name for f in default_families()}
    sets = {t: [r for r in rows if r["cand"] in names] for t, rows in sets.items()}
    L = ["# Drift selection rule on development seeds (issue 29)", "",
         "`python benchmarks/bench_drift_dev.py --candidates FILE --seeds 100-104 [--no-shift]`, `--candidates FILE "
         "--real F [--upto U]`, then `--rules dev_shift.jsonl --no-shift-rules dev_noshift.jsonl --real-candidates "
         "real_pf.jsonl --nested-candidates real_nested.jsonl`: every candidate of every channel (validation "
         "statistics on the fitting part; held-out RMS of the MEASURED residual after refitting on it, predicted with "
         "the per-sample distance rule), and the rule variants applied offline to the same candidates. Simulated: "
         "development seeds 100–104 of both simulators, disjoint from bench_drift_regime's 0–9, with and without the "
         "regime change from 60 %. Real: the shared first 60 % of the machine-tool log; *fitting part* = a "
         "pseudo-future INSIDE the benchmark's fitting parts (the first 36 %, fit on its first 60 % = 0–21.6 %, judged "
         "on 21.6–36 %; the first 48 %, fit on its first 80 % = 0–38.4 %, judged on 38.4–48 %): what a rule may be "
         "decided on; *pseudo-future* = the benchmark's splits (fit 0–36 % → 36–60 %, 0–48 % → 48–60 %): reported, "
         "not decided on. Every variant keeps the gates (below OLS on the ranking folds; > 1 SE and ≥ 5 % mean gain "
         "on the horizon and on the novelty folds; no fold above OLS·1.05).", ""]
    sims = {t: _group(r) for t, r in sets.items() if not t.startswith("real") and r}
    reals = {t: _group(r) for t, r in sets.items() if t.startswith("real") and r}
    for t, by in sims.items():
        logs = sorted({(k[0], k[1]) for k in by})
        L += [f"## {t} ({len(logs)} logs, {len(by)} channel cases)", "",
              "| rule | > OLS·1.05 | worst ratio | < OLS | geometric-mean ratio | channels whose median ratio ≥ 1 |",
              "|---|---|---|---|---|---|"]
        bad_lines = []
        for name, rule in RULES.items():
            res = {k: apply_rule(c, *rule)[:2] for k, c in by.items()}
            v = np.array([x for x, _ in res.values()])
            med = {}
            for (f, _, ch), (x, _) in res.items():
                med.setdefault((f, ch), []).append(x)
            notbelow = [f"{f} {ch} ({np.median(x):.3f})" for (f, ch), x in med.items() if np.median(x) >= 1 - 1e-9]
            bad = sorted(((x, k, c) for k, (x, c) in res.items() if x > TOLERATED_LOSS), reverse=True)
            L.append(f"| {name} | {len(bad)} | {v.max():.3f} | {int((v < 1 - 1e-9).sum())} | "
                     f"{np.exp(np.mean(np.log(v))):.3f} | {'; '.join(notbelow) or 'none'} |")
            if bad:
                bad_lines.append(f"* {name}: " + "; ".join(f"{k[0]} s{k[1]} {k[2]} {c} {x:.3f}×" for x, k, c in bad))
        L += ["", "Cases above OLS·1.05:", ""] + (bad_lines or ["* none"]) + [""]
    for t, by in reals.items():
        keys = sorted(by)
        L += [f"## {t}", "", "Held-out RMS ratio to OLS of the MEASURED residual (candidate returned):", "",
              "| rule | " + " | ".join(f"{_split_name(t, s)}, {ch}" for _, s, ch in keys) + " | above OLS | below |",
              "|---|" + "---|" * (len(keys) + 2)]
        for name, rule in RULES.items():
            res = [apply_rule(by[k], *rule) for k in keys]
            L.append(f"| {name} | " + " | ".join(f"{x:.3f} ({c})" for x, c, _ in res)
                     + f" | {sum(x > 1 + 1e-9 for x, _, _ in res)} | {sum(x < 1 - 1e-9 for x, _, _ in res)} |")
        L.append("")
    # the bands of what the default rule returns
    L += ["## 95 % bands of the returned model (default rule), held out", "",
          "Per band rule: coverage of the held-out MEASURED residual (median, min, cases in 90–98 %), median "
          "half-width μm. *fold_residual*: the conformal quantile of |residual| on the horizon and novelty folds × "
          "max(1, ρ); *rho_scaled*: of |residual| / max(1, ρ) × max(1, ρ); *rho_power*: q·max(1, ρ)^γ, γ the "
          "smallest making the folds' out-of-range rows (ρ > 1, and the farther half of them) covered at 95 % too.", "",
          "| data | cases | " + " | ".join(f"{b}: coverage median, min, in 90–98 % | {b}: ± median μm"
                                             for b in BAND_RULES) + " | γ (median, range) |",
          "|---|---|" + "---|---|" * len(BAND_RULES) + "---|"]
    default = next(r for r in RULES.values() if r[2] == _default_selection())
    for t, by in {**sims, **reals}.items():
        picked = [apply_rule(c, *default)[2] for c in by.values()]
        cells = []
        for b in BAND_RULES:
            cov = np.array([p["band_cover"][b] for p in picked])
            cells += [f"{np.median(cov):.2f}, {cov.min():.2f}, {int(((cov >= 0.9) & (cov <= 0.98)).sum())}/{len(cov)}",
                      f"{np.median([p['band_half'][b] for p in picked]):.3g}"]
        g = [p["band_gamma"] for p in picked]
        L.append(f"| {t} | {len(picked)} | " + " | ".join(cells) + f" | {np.median(g):g}, {min(g):g}–{max(g):g} |")
    if reals:
        L += ["", "Real log, per case (band rule: coverage, ± median μm):", "",
              "| data | case | " + " | ".join(BAND_RULES) + " | γ |", "|---|---|" + "---|" * len(BAND_RULES) + "---|"]
        for t, by in reals.items():
            for k in sorted(by):
                p = apply_rule(by[k], *default)[2]
                L.append(f"| {t} | {_split_name(t, k[1])}, {k[2]} | " + " | ".join(
                    f"{p['band_cover'][b]:.2f}, {p['band_half'][b]:.3g}" for b in BAND_RULES) + f" | {p['band_gamma']:g} |")
    L += [""] + fam_lines
    if grid_folder:
        L += render_grids(grid_folder)
    with atomic_write(out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L) + "\n")
    return L


def _default_selection():
    return "mean_gain"    # the library's only order (docs/decisions/006)


def _split_name(title, frac):
    """A real case's split in words: the benchmark's pseudo-futures, or the one inside its fitting part."""
    full = 0.6 * frac
    if "fitting part" in title:
        return f"fit 0–{full * frac:.1%} → {full * frac:.1%}–{full:.0%}"
    return f"fit 0–{full:.0%} → {full:.0%}–60%"


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


RANGE_NESTED = ((0.6, 0.6), (0.8, 0.8))   # (keep the first U of the real log's shared part, fit on F of it): inside
#                                           the benchmark's fitting parts (0–21.6 % → 21.6–36 %, 0–38.4 % → 38.4–48 %)
RANGE_PSEUDO_FUTURES = (0.6, 0.8)          # bench_drift_regime's real splits: 0–36 % → 36–60 %, 0–48 % → 48–60 %
# the development logs a rule is decided on (simulated kinds with seeds; the real log's fitting parts are added where
# the shared log is present) and the benchmark's simulated logs it is judged on after (issue 29's rounds)
DEV_LOGS = [(k, s) for k in ("lumped", "rod") for s in range(100, 105)] + \
           [(k, s) for k in ("lumped-ns", "rod-ns") for s in range(100, 103)]
JUDGED_SIMS = ("rod-j", "lumped-j", "rod-jns", "lumped-jns")
# the rounds of whole selections per variant (``--<name>-round FILE [--<name>-judge]``): {name: (variants (name →
# DriftSelector keyword arguments, the first the reference), heading of the rendered page, default page, the simulated
# kinds judged, the option helps)}
WHOLE_SELECTION_ROUNDS = {}


def round_logs(real_present: bool, judge: bool, judged_sims=JUDGED_SIMS) -> list:
    """[(kind, seed)] of a round: the development logs and the real fitting parts, or (``judge``) the real
    pseudo-futures and the benchmark's seeds 0–9 of ``judged_sims``; the real ones only where the shared log is."""
    if judge:
        return ([("real-pf", i) for i in range(len(RANGE_PSEUDO_FUTURES))] if real_present else []) + \
            [(k, s) for k in judged_sims for s in range(10)]
    return DEV_LOGS + ([("real", i) for i in range(len(RANGE_NESTED))] if real_present else [])



def range_case(kind, seed, variant, real_log, variants):
    """One log under one variant of ``variants``: rows {kind, seed, variant, channel,
    model, volcomp, ols, scale, rho, coverage, cpu_s}. ``kind``: "lumped" / "rod" (regime change), "lumped-ns" /
    "rod-ns" (none), "-j" / "-jns" the benchmark's seeds with / without it (judged), "real" (``seed`` = the index
    into ``RANGE_NESTED``; ``real_log`` the loaded shared log)."""
    if kind == "real":
        upto, ff = RANGE_NESTED[seed]
        log = head_of(real_log, upto)
    elif kind == "real-pf":          # the benchmark's pseudo-futures (judged, never decided on)
        ff = RANGE_PSEUDO_FUTURES[seed]
        log = real_log
    else:
        fam = kind.split("-")[0]       # "-j": the benchmark's seeds 0–9 (judged), with the regime change
        log = simulated_log(fam, seed, shift=not kind.endswith("ns"))   # "-ns", "-jns": none
        ff = SIM_SPLIT
    rep, cpu = selected_report(log, ff, variants[variant])
    return [{"kind": kind, "seed": seed, "variant": variant, "channel": ch, "model": r["model"],
             "volcomp": r["rms_after_um"], "ols": r["rms_ols_um"], "scale": r["distance_scale"],
             "rho": r["heldout_rho_median"], "coverage": r["band_coverage_heldout"], "cpu_s": cpu}
            for ch, r in rep.items()]


ROUND_SETS = {"dev, regime change (seeds 100–104)": ("lumped", "rod"), "dev, none (seeds 100–102)": ("lumped-ns", "rod-ns"),
              "real, inside the fitting parts": ("real",),
              "JUDGED: benchmark seeds 0–9, regime change (A: drift_regime_results.json)": ("lumped-j", "rod-j"),
              "JUDGED: benchmark seeds 0–9, no regime change (A: drift_regime_results.json)": ("lumped-jns", "rod-jns"),
              "JUDGED: real pseudo-futures 36–60 %, 48–60 % (A: drift_regime_results.json)": ("real-pf",)}


def render_range(rows, out, variants, head):
    """Markdown of a round of whole selections per variant (``head``: the first lines): per data set and variant, cases above 1.05× OLS, worst, below OLS (ratio
    < 0.9995), above OLS (> 1.0005), geometric-mean ratio; then every case whose ratio changed against A."""
    by = {}
    for r in rows:
        by.setdefault(r["variant"], {})[(r["kind"], r["seed"], r["channel"])] = r
    L = head+ ["",
         "| data | variant | cases | > 1.05× OLS | worst | below OLS | above OLS | geometric mean | CPU s |",
         "|---|---|---|---|---|---|---|---|---|"]
    for name, kinds in ROUND_SETS.items():
        for v in variants:
            rr = [r for k, r in by.get(v, {}).items() if k[0] in kinds]
            if not rr:
                continue
            q = np.array([r["volcomp"] / r["ols"] for r in rr])
            cpu = sum({(r["kind"], r["seed"]): r["cpu_s"] for r in rr}.values())
            L.append(f"| {name} | {v} | {len(q)} | {int((q > TOLERATED_LOSS).sum())} | {q.max():.3f} | "
                     f"{int((q < 0.9995).sum())} | {int((q > 1.0005).sum())} | {np.exp(np.mean(np.log(q))):.3f} | "
                     f"{cpu:.0f} |")
    L += ["", "Cases whose choice or ratio changed against A (kind, seed, channel: A → variant):", ""]
    for v in list(variants)[1:]:
        for k, r in sorted(by.get(v, {}).items(), key=lambda kv: str(kv[0])):
            a = by.get("A", {}).get(k)
            if a and (a["model"] != r["model"] or abs(a["volcomp"] - r["volcomp"]) > 1e-9 * max(1.0, a["volcomp"])):
                L.append(f"- {v}: {k[0]} {k[1]} {k[2]}: {a['model']} {a['volcomp'] / a['ols']:.3f}× (s = {a['scale']}) → "
                         f"{r['model']} {r['volcomp'] / r['ols']:.3f}× (s = {r['scale']})")
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
    ap.add_argument("--candidates", default=None, help="dump every candidate's statistics (JSON lines) to FILE")
    ap.add_argument("--rules", default=None, help="compare the rule variants offline on a --candidates FILE")
    ap.add_argument("--real-candidates", default=None, help="with --rules: the real log's candidates (--real F)")
    ap.add_argument("--no-shift-rules", default=None, help="with --rules: candidates of logs without regime change")
    ap.add_argument("--nested-candidates", default=None,
                    help="with --rules: the real log's candidates inside a fitting part (--real F --upto U)")
    ap.add_argument("--no-shift", action="store_true", help="with --candidates: the logs without regime change")
    ap.add_argument("--judge-candidates", default=None,
                    help="with --rules: candidates of the benchmark's seeds (--seeds 0-9), reported beside the "
                         "development seeds (judged, never decided on)")
    ap.add_argument("--grid-candidates", default=None,
                    help="with --rules: a folder of candidates dumped with --weights fine (dev.jsonl, devns.jsonl, "
                         "nested.jsonl, pf.jsonl, judge.jsonl, judgens.jsonl; those present): the blend grids compared")
    ap.add_argument("--with-families", action="store_true",
                    help="with --candidates: the measured non-default families are candidates too (their comparison "
                         "is a section of --rules' output)")
    ap.add_argument("--weights", default=None,
                    help="with --candidates: the blend weights w of the candidates, comma-separated (default: the "
                         "selector's SHRINK_WEIGHTS; 'fine': the steps of 1/8, which SHRINK_WEIGHTS is now)")
    ap.add_argument("--upto", type=float, default=None,
                    help="with --real: keep only the first UPTO of the log (a fitting part; its rest is never read)")
    ap.add_argument("--real", type=float, default=None,
                    help="dump the candidates of the real log fitted on this fraction (to --candidates FILE)")
    for name, (_, _, page, _, what, judged) in WHOLE_SELECTION_ROUNDS.items():
        ap.add_argument(f"--{name}-round", default=None,
                        help=f"{what}, one JSON line per finished log to FILE (resumed), then render --{name}-out")
        ap.add_argument(f"--{name}-judge", action="store_true",
                        help=f"with --{name}-round: after the decision, {judged} (A from drift_regime_results.json)")
        ap.add_argument(f"--{name}-out", default=str(Path(__file__).with_name(page)))
    a = ap.parse_args(argv)
    chosen = [n for n in WHOLE_SELECTION_ROUNDS if getattr(a, f"{n}_round")]
    if chosen:
        name = chosen[0]
        variants, head, _, judged_sims, _, _ = WHOLE_SELECTION_ROUNDS[name]
        path, judge, out = getattr(a, f"{name}_round"), getattr(a, f"{name}_judge"), getattr(a, f"{name}_out")
        done = set()
        rows = []
        if Path(path).exists():
            for line in Path(path).read_text().splitlines():
                if line.strip():
                    r = json.loads(line)
                    rows += r
                    done.add((r[0]["kind"], r[0]["seed"], r[0]["variant"]))
        real = load_drift_log(REAL) if REAL.exists() else None
        todo = round_logs(real is not None, judge, judged_sims)
        for k, s in todo:
            for v in variants:
                if (k, s, v) in done:
                    continue
                r = range_case(k, s, v, real, variants)
                rows += r
                with open(path, "a", encoding="utf-8") as fh:
                    fh.write(json.dumps(r) + "\n")
                print(f"{k} {s} {v}: " + ", ".join(f"{x['channel']} {x['volcomp'] / x['ols']:.3f}" for x in r),
                      file=sys.stderr, flush=True)
        print("\n".join(render_range(rows, out, variants, head)))
        return
    if a.weights == "fine":
        a.weights = SHRINK_WEIGHTS
    elif a.weights:
        a.weights = tuple(float(x) for x in a.weights.split(","))
    if a.rules:
        def rows_of(f):
            return [r for line in Path(f).read_text().splitlines() if line.strip() for r in json.loads(line)] if f else []
        sets = {"simulated, regime change from 60 %": rows_of(a.rules),
                "simulated, no regime change": rows_of(a.no_shift_rules),
                "real log, pseudo-future inside the fitting part (decided on)": rows_of(a.nested_candidates),
                "real log, the benchmark's pseudo-future (reported)": rows_of(a.real_candidates),
                "simulated, the benchmark's seeds 0–9, regime change (judged, not decided on)":
                    rows_of(a.judge_candidates)}
        print("\n".join(render_rules(sets, a.out, a.grid_candidates)))
        return
    if a.candidates and a.real is not None:
        log = load_drift_log(REAL)
        if a.upto is not None:      # the log's first ``upto`` only: a pseudo-future inside a fitting part
            log = head_of(log, a.upto)
        with open(a.candidates, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(candidates_of(log, a.real, "real", a.real, a.with_families, a.weights)) + "\n")
        return
    if a.candidates:
        lo, hi = (int(x) for x in a.seeds.split("-"))
        for f in a.families.split(","):
            for s in range(lo, hi + 1):
                t0 = time.process_time()
                r = candidates(f, s, shift=not a.no_shift, extra=a.with_families, weights=a.weights)
                with open(a.candidates, "a", encoding="utf-8") as fh:
                    fh.write(json.dumps(r) + "\n")
                ch = [x for x in r if x["chosen"]]
                print(f"{f} {s}: {time.process_time() - t0:.0f} CPU s; chosen " + ", ".join(
                    f"{x['channel']} {x['cand']} {x['heldout'] / x['heldout_ols']:.3f}" for x in ch),
                    file=sys.stderr, flush=True)
        return
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
