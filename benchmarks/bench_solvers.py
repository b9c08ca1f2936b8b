"""Solver benchmark (issue 4): residuals and throughput of traditional, ga, batched-ga, exact.

Side by side in one run, on the flute path (``compensation.toolpath.flute_path``, 2,800
points over 7 turns; a 7-turn helix when that module is missing), for two fields:

* ``htm``: the 23-element HTM field of the truth grinder ``random_truth(machine, 0)``;
* ``learned``: an :class:`training.model.MLPField` fitted by ``training.fit_field`` (LM, the
  paper's 3-10-15-25-15-10-3 sigmoid network) on the 11³ feature points of that HTM field,
  the iterate kept on 5,000 off-grid selection points (the product default).

``ga`` (PyGAD, one point at a time) runs on ``--ga-points`` points spread evenly along the
path, each timed alone (median per point). ``batched-ga`` runs on the full path (learned
field) or on ``--batched-points`` evenly spread points (HTM field, whose evaluation costs
~3.5 μs per point). Ratios are median ga seconds per point over the other solver's
seconds per point, in the same run. Residuals: the model residual (each solver against
its own field) and the true residual (the truth machine driven with the commands).

Scale: ``--scale N`` targets (default 1,000,000) through ``exact`` on the learned field, in
a child process whose peak RSS is read from ``getrusage``, limited to ``--threads`` threads.

    python benchmarks/bench_solvers.py                      # writes benchmarks/solvers_results.md
    python benchmarks/bench_solvers.py --quick              # a smoke run (small sizes)
    python benchmarks/bench_solvers.py --from-json benchmarks/solvers_results.json  # markdown only
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def set_threads(n: int) -> None:
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(k, str(n))
    import torch
    torch.set_num_threads(n)


def flute_targets(machine, n_points: int | None):
    """(targets (n, 3) mm, axes (n, 3), label) of the flute path (or a 7-turn helix)."""
    from errormap.chain_kernel import inverse
    try:
        from compensation.toolpath import flute_path
        fp = flute_path() if n_points is None else flute_path(points_per_turn=max(2, round(n_points / 7)))
        return fp.targets_mm, fp.axes(machine), f"flute_path() ({len(fp)} points, {fp.settings.turns} turns)"
    except ImportError:
        n = n_points or 2800
        t = np.linspace(0.0, 1.0, n)
        r = 0.3 + 0.7 * t
        th = np.deg2rad(7 * 360.0 * t)
        targets = np.column_stack([150.0 - 20.0 * t, r * np.sin(th), r * np.cos(th)])
        return targets, inverse(machine, targets, unwrap=True), f"7-turn helix ({n} points)"


def learned_field(machine, htm, max_time_s: float, seed: int = 0):
    from errormap.featurepoints import make_feature_points
    from errormap.seeds import spawn_rngs
    from errormap.simulator import random_axes
    from training.trainers import TrainSettings, fit_field
    fp = make_feature_points(machine, htm, n=11)
    r_val, r_sel = spawn_rngs(seed, 2)
    va = random_axes(machine, 5000, r_val)
    sa = random_axes(machine, 5000, r_sel)  # off-grid model selection, as the CLI
    settings = TrainSettings(trainer="lm", max_time_s=max_time_s, max_iter=100_000, seed=seed)  # the budget decides (fit_field's former default cap)
    fit = fit_field(fp, settings, validation=(va, htm.predict(va)), selection=(sa, htm.predict(sa)), track=False,
                    quiet=True)
    return fit.field, fit


def true_residual_um(truth, result):
    """Truth tool point with the commanded axes minus the target, μm (n, 3)."""
    n = len(result.axes)
    return (truth.tool_point(result.axes, **truth.default_conditions(n)) - result.targets_mm) * 1e3


def stats(res, truth):
    from compensation.evaluate import residual_metrics
    m = res.residual_norm_um
    mod, tru = residual_metrics(res.residual_um, "model"), residual_metrics(true_residual_um(truth, res), "true")
    return {"n": len(m), "model_max_um": mod["model_max_um"], "model_max_sq_um2": mod["model_max_sq_um2"],
            "model_mean_sq_um2": mod["model_mean_sq_um2"], "model_median_um": float(np.median(m)),
            "true_max_um": tru["true_max_um"], "true_mean_sq_um2": tru["true_mean_sq_um2"],
            "success": int(res.success.sum()), "nfev_per_point": res.nfev / len(m),
            "s_per_point": res.seconds / len(m), "seconds": res.seconds}


def timed(fn, repeats):
    """(result of the last call, median seconds over ``repeats`` calls)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times)), [float(t) for t in times]


def run_field(name, field, machine, truth, targets, axes, args, log):
    from compensation.solvers import SOLVERS, solve
    from errormap.threads import limit_threads
    n = len(targets)
    out = {}
    # one-time costs (imports, numba compilation, PyGAD set-up) stay out of the timings: every
    # solver of the registry once
    for method, spec in SOLVERS.items():
        kw = {"progress": False} if spec.progress else {}
        if spec.seeded:
            kw["generations"] = 2
        solve(method, field, targets[:2], machine, target_axes=axes[:2], **kw)
    log(f"[{name}] traditional on {n} points")
    out["traditional"] = stats(solve("traditional", field, targets, machine, target_axes=axes), truth)
    # each timed configuration: (label, torch threads, batched-ga workers)
    configs = [("cores", args.threads, None), ("1core", 1, 1)]  # None: the solver's default
    nb = n if name == "learned" else min(n, args.batched_points)
    sel_b = np.linspace(0, n - 1, nb).round().astype(int)
    timing = {}
    for label, threads, workers in configs:
        with limit_threads(threads):
            log(f"[{name}] exact on {n} points, {threads} thread(s), median of {args.exact_repeats}")
            r_ex, t_ex, all_ex = timed(lambda: solve("exact", field, targets, machine, target_axes=axes, progress=False),
                                       args.exact_repeats)
            log(f"[{name}] batched-ga on {nb} points, workers {workers or 'default'}, median of {args.batched_repeats}")
            r_bg, t_bg, all_bg = timed(lambda: solve("batched-ga", field, targets[sel_b], machine, target_axes=axes[sel_b],
                                                      seed=args.seed, workers=workers, progress=False),
                                       args.batched_repeats)
        timing[label] = {"threads": threads, "workers": r_bg.info["workers"], "exact_s": t_ex, "exact_all_s": all_ex,
                         "batched_s": t_bg, "batched_all_s": all_bg}
        if label == "cores":
            out["exact"], out["batched-ga"] = stats(r_ex, truth), stats(r_bg, truth)
    for m_, key, npts in (("exact", "exact_s", n), ("batched-ga", "batched_s", nb)):
        out[m_]["s_per_point"] = timing["cores"][key] / npts
        out[m_]["s_per_point_1core"] = timing["1core"][key] / npts
    out["timing"] = timing
    sel = np.linspace(0, n - 1, args.ga_points).round().astype(int)
    log(f"[{name}] ga (PyGAD) on {len(sel)} points, one call per point")
    per, results = [], []
    for i in sel:
        r = solve("ga", field, targets[i:i + 1], machine, target_axes=axes[i:i + 1], seed=args.seed, progress=False)
        per.append(r.seconds)
        results.append(r)
    from compensation.solvers.base import SolveResult
    cat = SolveResult("ga", *(np.concatenate([getattr(r, k) for r in results]) for k in
                              ("targets_mm", "commands_mm", "axes", "residual_um", "correction_um", "success")),
                      nfev=sum(r.nfev for r in results), seconds=float(sum(per)))
    out["ga"] = stats(cat, truth)
    out["ga"]["median_s_per_point"] = float(np.median(per))
    out["ga"]["quartiles_s_per_point"] = [float(np.percentile(per, 25)), float(np.percentile(per, 75))]
    # the other solvers on exactly the ga subset, for a like-for-like residual comparison
    sub = {}
    for method in ("traditional", "exact", "batched-ga"):
        kw = {"seed": args.seed} if method == "batched-ga" else {}
        if method != "traditional":
            kw["progress"] = False
        sub[method] = stats(solve(method, field, targets[sel], machine, target_axes=axes[sel], **kw), truth)
    out["on_ga_subset"] = sub
    if name == "learned" and args.seed_repeats:
        # residual quality over seeds, same points: is batched-ga's residual equal or better?
        log(f"[{name}] residual over seeds on the ga subset: ga × {args.seed_repeats}, batched-ga × {4 * args.seed_repeats}")
        seeds = {}
        for method, k in (("ga", args.seed_repeats), ("batched-ga", 4 * args.seed_repeats)):
            r2 = np.array([solve(method, field, targets[sel], machine, target_axes=axes[sel], seed=1000 + j,
                                 progress=False).residual_norm_um ** 2 for j in range(k)])
            seeds[method] = {"seeds": k, "mean_sq_um2": float(r2.mean()), "median_sq_um2": float(np.median(r2)),
                             "max_um": float(np.sqrt(r2.max())),
                             "mean_sq_per_seed": [float(v) for v in r2.mean(axis=1)]}
        out["over_seeds"] = seeds
    ga_s = out["ga"]["median_s_per_point"]
    out["ratios_vs_ga"] = {m: ga_s / out[m]["s_per_point"] for m in ("traditional", "batched-ga", "exact")}
    out["ratios_vs_ga_1core"] = {m: ga_s / out[m]["s_per_point_1core"] for m in ("batched-ga", "exact")}
    return out


def retry_cost(field, machine, targets, axes, seeds: int, log) -> dict:
    """batched-ga on the whole path over ``seeds`` seeds (0, 1, ...): per seed, the points above the
    tolerance after the paper's 400 generations (what was handed over before issue 30), what the
    retries and the Newton polish did with them, and their share of the solve time."""
    from compensation.solvers import solve
    runs = []
    for seed in range(seeds):
        r = solve("batched-ga", field, targets, machine, target_axes=axes, seed=seed, progress=False)
        st = dict(r.info["retry"])
        st.update(seed=seed, seconds=float(r.seconds), success=int(r.success.sum()), points=len(targets),
                  model_max_um=float(r.residual_norm_um.max()))
        runs.append(st)
        log(f"  seed {seed}: {st['retried']} retried (worst {st['worst_before_um']:.3g} um), "
            f"{st['polished']} polished, {st['unconverged']} unconverged, {st['retry_seconds']:.2f} of "
            f"{st['seconds']:.1f} s")
    return {"seeds": seeds, "runs": runs}


def scale_child(n: int, threads: int, model_dir: str) -> None:
    """Child process: ``exact`` on n random targets of the saved learned field; prints JSON."""
    set_threads(threads)
    from compensation.solvers import solve
    from errormap.chain_kernel import forward
    from errormap.machine import load_machine
    from errormap.simulator import random_axes
    from training.model import MLPField
    machine = load_machine()
    field = MLPField.load(model_dir)
    rng = np.random.default_rng(5)
    axes = random_axes(machine, n, rng)
    axes[:, 1] = np.maximum(axes[:, 1], 0.5)  # keep off the A axis' unreachable core
    targets = forward(machine, axes)
    t0 = time.perf_counter()
    r = solve("exact", field, targets, machine, target_axes=axes, progress=False)
    dt = time.perf_counter() - t0
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"n": n, "seconds": dt, "peak_rss_mb": rss_mb, "success": int(r.success.sum()),
                      "model_max_um": float(r.residual_norm_um.max()), "nfev_per_point": r.nfev / n}))


def retry_markdown(rt: dict) -> list:
    """The GA-retry section (issue 30) of the results page."""
    runs = rt["runs"]
    n = runs[0]["points"] if runs else 0
    retried = sum(r["retried"] for r in runs)
    L = ["## GA retries: no point handed over unconverged (issue 30)", "",
         f"`batched-ga` on the whole path ({n:,} points) with seeds 0…{rt['seeds'] - 1}, field: {rt['field']}"
         + (f"; run {rt['when']} (`{rt['command']}`, load average {rt['load']})" if rt.get("when") else "") + ". "
         "*Above tol after 400 generations* is what was handed over before the retries existed (its worst model "
         "residual beside it); those points were re-run from a fresh population around their best (up to 2 rounds), "
         "then Newton-polished; *unconverged* is what the `convergence` guard would still refuse. *Retry s* is the "
         "retries' and polish's wall time, *solve s* the whole batched-ga call's (the 400 generations included).", "",
         "| seed | above tol after 400 gen. | worst before μm | rounds | polished | unconverged | model max after μm "
         "| retry s | solve s | extra time |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        L.append(f"| {r['seed']} | {r['retried']} | {r['worst_before_um']:.3g} | {r['retry_rounds']} | {r['polished']} "
                 f"| {r['unconverged']} | {r['model_max_um']:.3g} | {r['retry_seconds']:.2f} | {r['seconds']:.1f} "
                 f"| {100 * r['retry_seconds'] / r['seconds']:.1f} % |")
    tot_s, tot_r = sum(r["seconds"] for r in runs), sum(r["retry_seconds"] for r in runs)
    L += ["", f"Over {len(runs)} seeds: {retried} of {n * len(runs):,} points above the tolerance after the paper's "
              f"generations, {sum(r['unconverged'] for r in runs)} unconverged after the retries; the retries "
              f"took {tot_r:.1f} s of {tot_s:.0f} s ({100 * tot_r / max(tot_s, 1e-12):.1f} %).", ""]
    return L


def write_markdown(path: Path, res: dict) -> None:
    nt = res["threads"]
    L = ["# Solver benchmark (issue 4)", "",
         f"Generated by `python benchmarks/bench_solvers.py` on {res['when']} ({res['host']}). "
         f"Path: {res['path']}. Seed {res['seed']}.", "",
         "Model residual = each solver against its own field; true residual = the truth machine "
         "(`random_truth(machine, 0)`, 23 elements, no undeclared effects) driven with the commands. "
         "`ga` = PyGAD per point on an evenly spread subset, timed one point per call (median). "
         f"`exact` and `batched-ga` are timed twice in the same run: on the machine's {nt} cores ({nt} torch "
         "threads; batched-ga with its default workers: one thread per core over equal chunks of points with "
         "the fused learned-field fitness, one with a generic field) and on 1 core (1 torch thread, 1 worker); "
         "medians of repeated runs. Ratios are ga's median s/point over the solver's "
         "s/point, same run. PyGAD's per-point loop is sequential (one core) in both.", ""]
    for fname, fr in res["fields"].items():
        L += [f"## Field: {fname}", "", fr.get("note", ""), "",
              "| solver | points | model max μm | model max² μm² | model mean² μm² | true max μm | true mean² μm² "
              f"| success | evals/point | s/point ({nt} cores) | × faster than ga | s/point (1 core) | × (1 core) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for m in ("traditional", "ga", "batched-ga", "exact"):
            s = fr[m]
            ratio = "1" if m == "ga" else f"{fr['ratios_vs_ga'][m]:.3g}"
            sp = s.get("median_s_per_point", s["s_per_point"])
            s1 = s.get("s_per_point_1core")
            r1 = fr.get("ratios_vs_ga_1core", {}).get(m)
            c1 = f"{s1:.3g} | {r1:.3g}" if s1 is not None else ("(one core) | 1" if m == "ga" else "– | –")
            L.append(f"| {m} | {s['n']} | {s['model_max_um']:.4g} | {s['model_max_sq_um2']:.4g} | "
                     f"{s['model_mean_sq_um2']:.3g} | {s['true_max_um']:.4g} | {s['true_mean_sq_um2']:.3g} | "
                     f"{s['success']}/{s['n']} | {s['nfev_per_point']:.0f} | {sp:.3g} | {ratio} | {c1} |")
        if "quartiles_s_per_point" in fr["ga"]:
            q1, q3 = fr["ga"]["quartiles_s_per_point"]
            L += ["", f"PyGAD per point: median {fr['ga']['median_s_per_point']:.3f} s, quartiles {q1:.3f}–{q3:.3f} s "
                  f"over {fr['ga']['n']} points."]
        if "timing" in fr:
            L += ["", "Individual timed runs (s): " + "; ".join(
                f"{lab} exact {', '.join(f'{t:.4f}' for t in tm['exact_all_s'])} / batched-ga "
                f"{', '.join(f'{t:.2f}' for t in tm['batched_all_s'])}" for lab, tm in fr["timing"].items())]
        L += ["", f"Same {fr['ga']['n']} points as ga (like for like):", "",
              "| solver | model max μm | model mean² μm² | true max μm |", "|---|---|---|---|"]
        for m, s in list(fr["on_ga_subset"].items()) + [("ga", fr["ga"])]:
            L.append(f"| {m} | {s['model_max_um']:.4g} | {s['model_mean_sq_um2']:.3g} | {s['true_max_um']:.4g} |")
        if "over_seeds" in fr:
            L += ["", f"The same {fr['ga']['n']} points over several seeds (model residual; seeds 1000…):", "",
                  "| solver | seeds | mean² μm² | median² μm² | max μm | mean² per seed (1e-5 μm²) |", "|---|---|---|---|---|---|"]
            for m, s in fr["over_seeds"].items():
                L.append(f"| {m} | {s['seeds']} | {s['mean_sq_um2']:.3g} | {s['median_sq_um2']:.3g} | {s['max_um']:.4g} | "
                         + ", ".join(f"{1e5 * v:.2f}" for v in s["mean_sq_per_seed"]) + " |")
        L.append("")
    if res.get("scale"):
        s = res["scale"]
        L += ["## Scale: exact on the learned field", "",
              f"{s['n']:,} random targets (z ≥ 0.5 mm), {res['threads']} threads, child process: "
              f"{s['seconds']:.1f} s, peak RSS {s['peak_rss_mb']:.0f} MB, {s['success']:,} succeeded, "
              f"model max {s['model_max_um']:.3g} μm, {s['nfev_per_point']:.1f} evaluations per point."]
        if "learned" in res["fields"]:
            ga_s = res["fields"]["learned"]["ga"]["median_s_per_point"]
            L.append(f"Per point {1e6 * s['seconds'] / s['n']:.1f} μs: {ga_s * s['n'] / s['seconds']:,.0f}× faster than "
                     f"ga's median {ga_s:.2f} s per point on the same field in this run (the 2,800-point path "
                     "figure above includes per-call fixed costs).")
        L.append("")
    if res.get("retry"):
        L += retry_markdown(res["retry"])
    L += ["## Targets (issue 4), this run", "",
          "| target | field | measured | met |", "|---|---|---|---|"]
    for fname, fr in res["fields"].items():
        for lab, ratios in ((f"{nt} cores", fr["ratios_vs_ga"]), ("1 core", fr.get("ratios_vs_ga_1core"))):
            if not ratios:
                continue
            rb, re_ = ratios["batched-ga"], ratios["exact"]
            L.append(f"| batched-ga ≥ 300× ga ({lab}) | {fname} | {rb:.0f}× | "
                     f"{'yes' if rb >= 300 else f'no ({300 / rb:.1f}× short)'} |")
            L.append(f"| exact ≥ 100,000× ga, 2,800-point path ({lab}) | {fname} | {re_:,.0f}× | "
                     f"{'yes' if re_ >= 1e5 else f'no ({1e5 / re_:.2f}× short)'} |")
        for m, lim in (("ga", 0.265), ("batched-ga", 0.265), ("exact", 0.001)):
            v = fr[m]["model_max_um"]
            L.append(f"| {m} max model residual ≤ {lim} μm | {fname} | {v:.3g} μm | {'yes' if v <= lim else 'no'} |")
    if res.get("scale") and "learned" in res["fields"]:
        s = res["scale"]
        r1 = res["fields"]["learned"]["ga"]["median_s_per_point"] * s["n"] / s["seconds"]
        L.append(f"| exact ≥ 100,000× ga (1M scale run) | learned | {r1:,.0f}× | {'yes' if r1 >= 1e5 else 'no'} |")
        L.append(f"| 1M targets ≤ 60 s, ≤ 2 GB | learned | {s['seconds']:.1f} s, {s['peak_rss_mb']:.0f} MB "
                 f"({res['threads']} thread(s)) | {'yes' if s['seconds'] <= 60 and s['peak_rss_mb'] <= 2048 else 'no'} |")
    L.append("")
    L += ["## Notes", "",
          "* `batched-ga` performs the same ≈ 12,000 field evaluations per point as PyGAD (same GA: same operators, "
          "parameters, 400 generations, no early stop); its speed comes from doing them well: the generation step "
          "(selection, crossover, mutation, ball repair, fitness inheritance) is one compiled pass over all points "
          "(`compensation/solvers/_ga_kernels.py`, numba), and on the learned field the fitness is one float32 "
          "torch pipeline (nominal IK, then the network on columns with its scalings folded into the first and "
          "last layers). On the HTM field the fitness is the field's own float64 `predict` (≈ 3.5 μs per "
          "evaluation), which bounds the ratio there.",
          "* Fair configuration: both GAs evaluate the learned field in float32 (PyGAD through "
          "`field_error_um(fast=True)`, i.e. `MLPField.predict(dtype=float32)`, 40 individuals per call with "
          "`fitness_batch_size=40`, small calls on one torch thread; batched-ga through `predict_columns`: the "
          "same float32 network, a few nm apart). `exact` starts Newton from a float32 value and Jacobian; every "
          "later value, and every reported residual, is float64.",
          "* The learned field (raw A input) is seam-closed at inference (`MLPField`, docs/explanation/solvers.md): periodic "
          "and continuous in A, so targets at A = 360°·k have roots.",
          f"* Load average (1/5/15 min) before: {res.get('load_before', '?')}; after: {res.get('load_after', '?')}. "
          "This 2-core VM's speed drifts (the same call varied by up to 1.5× within minutes while this was "
          "written); ratios are therefore taken side by side in one run, from medians.", ""]
    L += ["## Paper (for reference)", "",
          "Traditional max squared residual 160.0585 μm² → GA 0.07048 μm² (max ≈ 12.65 → 0.265 μm); "
          "mean squared 45.8476 → 0.0003 μm².", ""]
    path.write_text("\n".join(L))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ga-points", type=int, default=30)
    ap.add_argument("--batched-points", type=int, default=280, help="batched-ga points on the HTM field")
    ap.add_argument("--path-points", type=int, default=None, help="flute points (default: flute_path's)")
    ap.add_argument("--train-s", type=float, default=120.0, help="LM training budget of the learned field")
    ap.add_argument("--scale", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--exact-repeats", type=int, default=11, help="timed exact runs per configuration (median)")
    ap.add_argument("--batched-repeats", type=int, default=3, help="timed batched-ga runs per configuration (median)")
    ap.add_argument("--seed-repeats", type=int, default=3, help="ga seeds (batched-ga: 4×) for the residual comparison")
    ap.add_argument("--fields", default="htm,learned")
    ap.add_argument("--out", default=str(HERE / "solvers_results.md"))
    ap.add_argument("--quick", action="store_true", help="smoke run: 4 ga points, 40 batched, 200-point path")
    ap.add_argument("--from-json", help="only rewrite the markdown from a results JSON")
    ap.add_argument("--scale-child", nargs=2, metavar=("N", "MODEL_DIR"), help=argparse.SUPPRESS)
    ap.add_argument("--retry-seeds", type=int, default=20,
                    help="batched-ga seeds on the whole path for the GA-retry figures (learned field)")
    ap.add_argument("--retry-only", action="store_true",
                    help="only the GA-retry section, added to the existing results JSON beside --out")
    ap.add_argument("--retry-model", default=None,
                    help="for --retry-only: the field to use (MLflow run id / runs:/ URI / element-set JSON) "
                         "instead of training one")
    ap.add_argument("--tracking-uri", default=None, help="MLflow tracking URI for --retry-model")
    args = ap.parse_args(argv)
    if args.from_json:
        write_markdown(Path(args.out), json.loads(Path(args.from_json).read_text()))
        return 0
    if args.scale_child:
        scale_child(int(args.scale_child[0]), args.threads, args.scale_child[1])
        return 0
    if args.quick:
        args.ga_points, args.batched_points, args.path_points, args.train_s, args.scale = 4, 40, 200, 20.0, 20_000
        args.exact_repeats, args.batched_repeats, args.seed_repeats = 3, 1, 1
    set_threads(args.threads)
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    from errormap.simulator import random_truth

    def log(msg):
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)

    machine = load_machine()
    truth = random_truth(machine, 0)
    htm = ChainField(machine, truth.elements)
    targets, axes, path_label = flute_targets(machine, args.path_points)
    res = {"load_before": " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?",
           "when": time.strftime("%Y-%m-%d %H:%M"), "host": f"{platform.node()}, {os.cpu_count()} CPUs",
           "threads": args.threads, "seed": args.seed, "path": path_label, "fields": {}}
    if args.retry_only:
        return retry_only(args, machine, htm, targets, axes, log)
    wanted = args.fields.split(",")
    model_dir = None
    if "htm" in wanted:
        res["fields"]["htm"] = run_field("htm", htm, machine, truth, targets, axes, args, log)
        res["fields"]["htm"]["note"] = ("HTM field = the truth's own 23 elements (so the true residual equals the "
                                        f"model residual up to float rounding). batched-ga on {args.batched_points} "
                                        "evenly spread points.")
    if "learned" in wanted:
        log(f"training the learned field (LM, ≤ {args.train_s:g} s)")
        field, fit = learned_field(machine, htm, args.train_s, args.seed)
        model_dir = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_solvers_model_{os.getpid()}"
        field.save(model_dir)
        res["fields"]["learned"] = run_field("learned", field, machine, truth, targets, axes, args, log)
        if args.retry_seeds:
            log(f"[learned] GA retries: batched-ga on {len(targets)} points × {args.retry_seeds} seeds")
            res["retry"] = retry_cost(field, machine, targets, axes, args.retry_seeds, log)
            res["retry"]["field"] = "the learned field above"
        res["fields"]["learned"]["note"] = (
            f"Learned field: `training.fit_field` (LM, {fit.seconds:.0f} s, stop: {fit.history.stop_reason}); "
            f"metrics: " + ", ".join(f"{k} {v:.3g}" for k, v in fit.metrics.items() if isinstance(v, float)) + ".")
    if model_dir is not None and args.scale:
        log(f"scale: exact on {args.scale:,} targets (child process)")
        out = subprocess.run([sys.executable, __file__, "--threads", str(args.threads), "--scale-child",
                              str(args.scale), str(model_dir)], capture_output=True, text=True, check=True)
        res["scale"] = json.loads(out.stdout.strip().splitlines()[-1])
    if Path("/proc/loadavg").exists():
        res["load_after"] = " ".join(Path("/proc/loadavg").read_text().split()[:3])
    (Path(args.out).with_suffix(".json")).write_text(json.dumps(res, indent=2))
    write_markdown(Path(args.out), res)
    log(f"wrote {args.out}")
    return 0


def retry_only(args, machine, htm, targets, axes, log) -> int:
    """``--retry-only``: the GA-retry section alone, merged into the existing results JSON."""
    js = Path(args.out).with_suffix(".json")
    res = json.loads(js.read_text()) if js.exists() else {"fields": {}}
    if args.retry_model:
        from compensation.compensate import load_model
        field = load_model(args.retry_model, machine, tracking_uri=args.tracking_uri)
        label = f"`{args.retry_model}`"
    else:
        log(f"training the learned field (LM, ≤ {args.train_s:g} s)")
        field, fit = learned_field(machine, htm, args.train_s, args.seed)
        label = f"a learned field trained for this section (LM, {fit.seconds:.0f} s)"
    load0 = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"
    log(f"GA retries: batched-ga on {len(targets)} points × {args.retry_seeds} seeds")
    res["retry"] = retry_cost(field, machine, targets, axes, args.retry_seeds, log)
    load1 = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"
    res["retry"].update(field=label, when=time.strftime("%Y-%m-%d %H:%M"), load=f"{load0} → {load1}",
                        command="python benchmarks/bench_solvers.py " + " ".join(sys.argv[1:]))
    js.write_text(json.dumps(res, indent=2))
    write_markdown(Path(args.out), res)
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
