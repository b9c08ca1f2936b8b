"""Error budget of the closed loop's learned stage (issue 28): bias or variance?

A diagnostic, judged against the hidden truth and used for no choice. Per case and seed (default family)
the truth machine is held fixed — its elements and effect, the sweeps (the identification's input, same
noise), the checks' points, temperatures and directions — and only the check measurements' noise is
redrawn (``volcomp simulate --seed-check-noise``; draw 0 is the seed's own noise, the results table's run,
bit for bit). Each draw runs the user's path of :mod:`benchmarks.bench_hybrid` (identify → diagnose →
compensate the 2,000 volume points) and keeps the TRUE residual vector of every volume point. Over the
K draws, per volume point p, the compensated residual r_k(p) (μm, a 3-vector) splits into

* bias: r̄(p) = mean over the draws (the part common to every noise draw), B² = mean_p |r̄|² − V/K;
* variance: V = Σ_k mean_p |r_k − r̄|² / (K − 1) (the spread across draws; unbiased per draw),

so the expected squared TRUE RMS of one run is B² + V. The same for the same seed's machine without the
effect (n) and for the loop alone (parametric). The learned part's own error per draw is the field
d_k(p) = r_k(p) − r_k^none(p) (same seed, same noise vectors: the checks' noise does not depend on the
truth), split the same way.

Writes ``benchmarks/hybrid_budget_results.json`` (per run and per case/seed) and
``benchmarks/hybrid_budget_results.md``. Run:
``python benchmarks/bench_hybrid_budget.py --cases a_tilt,bump --seeds 3 --draws 4``
(``--report-only`` rebuilds the Markdown from the JSON; per-point residuals are cached in ``--cache``).
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_k, "1")

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
RESULTS_JSON = HERE / "hybrid_budget_results.json"
RESULTS_MD = HERE / "hybrid_budget_results.md"
DRAW_KEY = 0xB0D6E7
"""The k-th redraw (k ≥ 1) of a seed's check noise uses ``SeedSequence([seed, DRAW_KEY, k])`` (draw 0: the
seed's own noise, ``--seed-check-noise`` not given)."""


def draw_seed(seed: int, k: int):
    if k == 0:
        return None
    return int(np.random.SeedSequence([seed, DRAW_KEY, k]).generate_state(1)[0])


def _cache_path(cache: Path, case: str, seed: int, k: int, scale: float) -> Path:
    return cache / f"{case}_x{scale:g}_s{seed}_d{k}.npz"


def run_one(case, seed, k, scale, cache: Path) -> dict:
    import bench_hybrid
    from bench_hybrid import run_case
    bench_hybrid.GA_SEEDS = 0   # the GA subset is a solver figure, not a residual: not run for the budget
    p = _cache_path(cache, case, seed, k, scale)
    meta = p.with_suffix(".json")
    if p.is_file() and meta.is_file():
        return json.loads(meta.read_text())
    row = run_case("default", seed, case, scale=scale, check_noise_seed=draw_seed(seed, k), residuals=True)
    res = row.pop("residuals_um")
    np.savez_compressed(p, **res)
    row["draw"], row["check_noise_seed"] = k, draw_seed(seed, k)
    meta.write_text(json.dumps(row))
    return row


def decompose(r: np.ndarray) -> dict:
    """r: (K, P, 3) residuals over K draws. Bias, variance and the mean per-draw MSE (μm²)."""
    K = r.shape[0]
    rbar = r.mean(axis=0)
    v = float(np.sum(np.mean(np.sum((r - rbar) ** 2, axis=2), axis=1)) / (K - 1))
    b2 = float(np.mean(np.sum(rbar**2, axis=1)) - v / K)
    mse = float(np.mean(np.sum(r**2, axis=2)))
    return {"mse_um2": mse, "bias2_um2": b2, "var_um2": v, "rms_um": float(np.sqrt(mse)),
            "bias_rms_um": float(np.sqrt(max(b2, 0.0))), "sd_um": float(np.sqrt(v)),
            "per_draw_rms_um": [float(np.sqrt(np.mean(np.sum(x**2, axis=1)))) for x in r]}


def budget(case, seed, draws, scale, cache: Path) -> dict:
    def load(c, sc, label):
        return np.stack([np.load(_cache_path(cache, c, seed, k, sc))[label] for k in range(draws)])
    h, p = load(case, scale, "hybrid"), load(case, scale, "parametric")
    n = load("none", 1.0, "hybrid")
    metas = [json.loads(_cache_path(cache, case, seed, k, scale).with_suffix(".json").read_text()) for k in range(draws)]
    own_bias, left = (h - n).mean(axis=0), (p - n).mean(axis=0)
    alpha = float(np.sum(own_bias * left) / np.sum(left * left))
    explained = float(1.0 - np.sum((own_bias - alpha * left) ** 2) / np.sum(own_bias**2))
    return {"case": case, "seed": seed, "scale": scale, "draws": draws,
            # the learned part's common error along what the loop leaves of the effect (mean over draws of
            # r_parametric − r_none): own bias ≈ α·leftover is the learner taking only (1 − α) of it (shrinkage)
            "shrinkage": {"alpha": alpha, "explained": explained},
            "learned_kept": sum(bool(m["learned_kept"]) for m in metas),
            "families": [m.get("learned_family") for m in metas],
            "replaced_terms": sum(bool(m.get("replaced_terms")) for m in metas),
            "hybrid": decompose(h), "parametric": decompose(p), "none": decompose(n),
            "own": decompose(h - n)}


HEADER = ("Default family, 800 checks at 1 μm, 2,000 volume points; per seed the truth machine, the sweeps and the "
          "checks' layout fixed, only the checks' noise redrawn (draw 0 = the results table's run). TRUE = against "
          "the hidden truth (a diagnostic: used for no choice). Per seed: RMS = √(mean over draws of the squared "
          "TRUE RMS); bias = √B² (the part of the residual common to all draws); sd = √V (the spread across draws); "
          "B² + V = RMS². 'own' = the learned part's own error field r_k − r_k^none (same seed, same noise vectors). "
          "Rows 'all': means over the seeds of the squared figures, then √. 'excess bias share' = (B²_h − B²_n) / "
          "(h² − n²): the share of what the effect adds to the hybrid's mean square that is common to every draw. "
          "'leftover' = the mean over draws of r_parametric − r_none (what the loop alone leaves of the effect, the "
          "learned part's target); α = ⟨own bias, leftover⟩ / ⟨leftover, leftover⟩ over the volume points (raw draw "
          "means): α > 0 is the learner taking only 1 − α of its target, and the share of the own bias's mean "
          "square that α·leftover explains.")


def table_lines(doc: dict, per_seed: bool = True) -> list:
    L = ["| case | scale | seed | learned kept | hybrid RMS h (μm) | h bias | h sd | no-effect RMS n | n bias | n sd | "
         "h/n | loop alone p | p/h | own RMS | own bias | own sd | excess bias share | own bias = α·leftover: α "
         "(share of own bias² explained) |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    grp = {}
    for b in sorted(doc["budgets"], key=lambda b: (b["case"], b["scale"], b["seed"])):
        grp.setdefault((b["case"], b["scale"]), []).append(b)

    def line(label, seed, bs):
        m = lambda who, key: float(np.sqrt(max(np.mean([b[who][key] for b in bs]), 0.0)))
        h, n, p = m("hybrid", "mse_um2"), m("none", "mse_um2"), m("parametric", "mse_um2")
        db2 = np.mean([b["hybrid"]["bias2_um2"] - b["none"]["bias2_um2"] for b in bs])
        dv = np.mean([b["hybrid"]["var_um2"] - b["none"]["var_um2"] for b in bs])
        share = db2 / (db2 + dv) if (db2 + dv) > 0 else float("nan")
        kept = sum(b["learned_kept"] for b in bs)
        return (f"| {label[0]} | ×{label[1]:g} | {seed} | {kept}/{sum(b['draws'] for b in bs)} | {h:.3f} | "
                f"{m('hybrid', 'bias2_um2'):.3f} | {m('hybrid', 'var_um2'):.3f} | {n:.3f} | {m('none', 'bias2_um2'):.3f} | "
                f"{m('none', 'var_um2'):.3f} | {h / n:.2f} | {p:.3f} | {p / h:.2f} | {m('own', 'mse_um2'):.3f} | "
                f"{m('own', 'bias2_um2'):.3f} | {m('own', 'var_um2'):.3f} | {share:.0%} | {_shrink(bs)} |")

    for key, bs in sorted(grp.items()):
        if per_seed:
            L += [line(key, b["seed"], [b]) for b in bs]
        L.append(line(key, f"all ({len(bs)})", bs))
    return L


def _shrink(bs) -> str:
    v = [b["shrinkage"] for b in bs if "shrinkage" in b]
    if not v:
        return "—"
    return f"{np.mean([x['alpha'] for x in v]):.2f} ({np.mean([x['explained'] for x in v]):.0%})"


def write_report(doc: dict, argv) -> None:
    from errormap.io import atomic_write
    L = ["# Error budget of the learned stage (issue 28)", "",
         "Generated by `python benchmarks/bench_hybrid_budget.py " + " ".join(argv) + "` (module doc: the method). "
         + HEADER, ""] + table_lines(doc)
    L += ["", "Per draw: TRUE RMS (μm) of the hybrid, of the no-effect machine and of the loop alone; draw 0 first.", "",
          "| case | scale | seed | hybrid per draw | no-effect per draw | loop alone per draw | learned family per draw |",
          "|---|---|---|---|---|---|---|"]
    for b in sorted(doc["budgets"], key=lambda b: (b["case"], b["scale"], b["seed"])):
        f = lambda who: ", ".join(f"{x:.3f}" for x in b[who]["per_draw_rms_um"])
        L.append(f"| {b['case']} | ×{b['scale']:g} | {b['seed']} | {f('hybrid')} | {f('none')} | {f('parametric')} | "
                 f"{', '.join(str(x) for x in b['families'])} |")
    L.append("")
    with atomic_write(RESULTS_MD, "w", encoding="utf-8") as fh:
        fh.write("\n".join(L))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="a_tilt,bump")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed-start", type=int, default=0)
    ap.add_argument("--draws", type=int, default=4, help="noise draws per seed (draw 0 = the seed's own noise)")
    ap.add_argument("--scale", type=float, default=1.0, help="the effect's amplitude times this (bench_hybrid --scale)")
    ap.add_argument("--cache", default="/tmp/hybrid_budget_cache", help="per-point residuals of each run (npz)")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args(argv)
    argv = sys.argv[1:] if argv is None else argv
    from errormap.io import write_json
    doc = json.loads(RESULTS_JSON.read_text()) if RESULTS_JSON.is_file() else {"runs": [], "budgets": []}
    if args.report_only and Path(args.cache).is_dir():   # recompute the budgets from the cached residuals
        for i, b in enumerate(doc["budgets"]):
            try:
                doc["budgets"][i] = budget(b["case"], b["seed"], b["draws"], b["scale"], Path(args.cache))
            except FileNotFoundError:
                pass
        write_json(RESULTS_JSON, doc)
    if not args.report_only:
        cache = Path(args.cache)
        cache.mkdir(parents=True, exist_ok=True)
        runs = {(r["effect"], r["seed"], r["draw"]): r for r in doc["runs"]}
        buds = {(b["case"], b["seed"], b["scale"]): b for b in doc["budgets"]}
        for seed in range(args.seed_start, args.seed_start + args.seeds):
            for k in range(args.draws):
                for case, sc in [("none", 1.0)] + [(c, args.scale) for c in args.cases.split(",")]:
                    r = run_one(case, seed, k, sc, cache)
                    runs[(r["effect"], seed, k)] = {x: r.get(x) for x in (
                        "family", "seed", "effect", "draw", "check_noise_seed", "learned_kept", "learned_family",
                        "replaced_terms", "hybrid", "parametric", "held_final_um", "noise_floor_um", "cpu_s")}
                    print(json.dumps({x: runs[(r["effect"], seed, k)][x] for x in
                                      ("seed", "effect", "draw", "learned_kept", "hybrid", "cpu_s")}), flush=True)
            for c in args.cases.split(","):
                buds[(c, seed, args.scale)] = budget(c, seed, args.draws, args.scale, cache)
            doc = {"runs": list(runs.values()), "budgets": list(buds.values())}
            write_json(RESULTS_JSON, doc)
            write_report(doc, argv)
    write_report(doc, argv)


if __name__ == "__main__":
    main()
