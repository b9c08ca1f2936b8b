"""Benchmark : the network and the batched GA over a machine-tool chain (``mill-xyz``).

One process, one after the other (same load):

1. **train** — a smooth simulated element set of ``mill-xyz`` (±10 μm / μrad at 5 stations per axis,
   a cubic spline; seed 101) gives ``--grid``³ feature points (``make_feature_points``, what
   ``volcomp featurepoints`` writes); :func:`training.chain_model.fit_chain_field` trains the paper's
   10-15-25-15-10 network (LM, ``--iters`` iterations, seed 0, iterate selection on 5,000 points);
   reported: max / RMS fit error on the grid and on 10,000 random off-grid points of the same element
   set (true field), beside the plain OLS baseline (affine least squares on the axes) on the same
   points, and the training CPU seconds.
2. **solve** — ``--points`` seeded random targets of ``mill-xyz`` with the :class:`errormap.chain_field.ChainField`
   of a ±20 μm element set at 11 stations (seed 11): ``exact`` and ``batched-ga`` (seed 0) through the
   solver registry; reported: MODEL residual (``p_r + E(q) − p_d``, recomputed with the numpy chain)
   max / RMS, points converged, CPU seconds (``time.process_time``).

    nice -n 10 python benchmarks/bench_mt_train.py                       # full: grid 11, 200 its, 10k points
    nice -n 10 python benchmarks/bench_mt_train.py --grid 7 --iters 50 --points 500   # smoke
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bench_mt_solve import chain_elements

HERE = Path(__file__).resolve().parent


def train_case(grid, iters):
    from errormap.featurepoints import FeaturePoints, make_feature_points
    from errormap.machine import load_machine
    from errormap.chain_field import ChainField
    from errormap.seeds import spawn_seeds
    from training.chain_model import fit_chain_field, ols_baseline, random_chain_axes
    from training.trainers import TrainSettings, fit_metrics
    mt = load_machine("mill-xyz")
    el = chain_elements(mt, 101, scale=10.0, n_stations=5)
    with tempfile.TemporaryDirectory() as d:
        el_path = el.save(Path(d) / "truth.json")
        truth = ChainField(mt, el)
        fp = make_feature_points(mt, truth, grid, meta={"elements_file": str(el_path)})
        fp.save(Path(d) / "fp.csv")
        fp = FeaturePoints.load(Path(d) / "fp.csv")
        r = fit_chain_field(fp, mt, TrainSettings(max_iter=iters, seed=0), quiet=True)
    va = random_chain_axes(mt, 10_000, spawn_seeds(0, 2)[0])
    ve = truth.predict(va)
    base = fit_metrics("val", ols_baseline(r.field, fp.axes, fp.errors_um, va), ve)
    m = r.metrics
    return {"grid": f"{grid}^3 = {len(fp.axes)}", "iterations": m["iterations"], "cpu_s": m["train_cpu_seconds"],
            "train_max": m["train_max_um"], "train_rms": m["train_rms_um"], "val_max": m["val_max_um"],
            "val_rms": m["val_rms_um"], "ols_max": base["val_max_um"], "ols_rms": base["val_rms_um"],
            "field_max": float(np.abs(ve).max())}


def solve_case(n):
    from compensation.solvers import solve
    from errormap.machine import load_machine
    from errormap.chain_field import ChainField
    mt = load_machine("mill-xyz")
    f = ChainField(mt, chain_elements(mt, 11))
    rng = np.random.default_rng(12)
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, 3))
    t = mt.nominal(ax)
    solve("exact", f, t[:100], mt, target_axes=ax[:100], progress=False)  # compiled kernels loaded
    rows = []
    for meth in ("exact", "batched-ga"):
        c0 = time.process_time()
        r = solve(meth, f, t, mt, target_axes=ax, progress=False, **({"seed": 0} if meth != "exact" else {}))
        c = time.process_time() - c0
        nr = np.linalg.norm((mt.nominal(r.axes) - t) * 1e3 + f.predict(r.axes), axis=1)
        rows.append({"method": meth, "cpu_s": c, "max": float(nr.max()), "rms": float(np.sqrt(np.mean(nr ** 2))),
                     "ok": int(r.success.sum()), "n": n})
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=11)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--out", default=str(HERE / "mt_train_results.md"))
    a = ap.parse_args()
    tr = train_case(a.grid, a.iters)
    rows = solve_case(a.points)
    lines = ["# The network and the batched GA over a machine-tool chain (mill-xyz)", "",
             f"`nice -n 10 python benchmarks/bench_mt_train.py --grid {a.grid} --iters {a.iters} --points {a.points}`",
             "(one process; CPU seconds from `time.process_time`).", "",
             "## train (smooth simulated field, max |error| "
             f"{tr['field_max']:.1f} μm; paper network, LM, seed 0)", "",
             "| feature points | iterations | CPU s | grid max μm | grid RMS μm | off-grid max μm | off-grid RMS μm "
             "| OLS baseline off-grid max / RMS μm |", "|---|---|---|---|---|---|---|---|",
             f"| {tr['grid']} | {tr['iterations']} | {tr['cpu_s']:.1f} | {tr['train_max']:.4f} | {tr['train_rms']:.4f} "
             f"| {tr['val_max']:.4f} | {tr['val_rms']:.4f} | {tr['ols_max']:.2f} / {tr['ols_rms']:.2f} |", "",
             "Off-grid: 10,000 random points over the strokes, residual against the true (simulated) field.", "",
             f"## solve ({a.points:,} random targets, ±20 μm element set; MODEL residual)", "",
             "| method | CPU s | converged | max μm | RMS μm |", "|---|---|---|---|---|"]
    lines += [f"| {r['method']} | {r['cpu_s']:.2f} | {r['ok']}/{r['n']} | {r['max']:.3g} | {r['rms']:.3g} |" for r in rows]
    from errormap.io import atomic_write
    with atomic_write(a.out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
