"""Identification benchmark: noise-free exactness and noise propagation (σ = 2 μm).

    python benchmarks/bench_identification.py [--draws 100] [--out benchmarks/identification_results.md]

Truth: ``random_truth(builtin grinder, seed 3)``; 10,000 random axis points (seed 2024).
1. Noise-free sweeps (both gauges): max |spatial error difference| identified vs truth.
2. σ = 2 μm, noise seed 0: RMS and max of the spatial-error prediction error.
3. Monte Carlo over ``--draws`` noise draws (seeds 1..N; the tracker pose is redrawn with
   the noise): distribution of RMS and max, and the pointwise propagated RMS
   ``sqrt(mean over points of E_draws ‖Δe‖²)``. All are the MODEL residual of the
   identified HTM field against the truth field (no compensation involved).
"""
from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from errormap.chain_field import ChainField  # noqa: E402
from errormap.uncertainty import smooth_identify  # noqa: E402
from errormap.io import atomic_write  # noqa: E402
from errormap.machine import load_machine  # noqa: E402
from errormap.progress import Progress  # noqa: E402
from errormap.simulator import random_axes, random_truth  # noqa: E402
from errormap.stats import residual_stats  # noqa: E402
from errormap.sweeps import simulate_sweeps  # noqa: E402


def identify(sweeps, machine, gauge="first-station"):
    """The interpolating identification (the one method, on the grinder's chain) in ``gauge``."""
    return smooth_identify(sweeps, machine, smooth=False, gauge=gauge).raw


def err_stats(d):
    """(RMS, max) of the vector norm: errormap.stats.residual_stats."""
    st = residual_stats(d)
    return st["rms_um"], st["max_um"]


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--noise-um", type=float, default=2.0)
    ap.add_argument("--out", default=str(Path(__file__).with_name("identification_results.md")))
    args = ap.parse_args(argv)
    m = load_machine()
    truth = random_truth(m, 3)
    pts = random_axes(m, 10_000, np.random.default_rng(2024))
    e_true = ChainField(m, truth.elements).predict(pts)
    t0 = time.perf_counter()
    free = {}
    for gauge in ("first-station", "reference-line"):
        res = identify(simulate_sweeps(truth, noise_um=0.0, seed=0), m, gauge=gauge)
        free[gauge] = np.abs(ChainField(m, res.elements_).predict(pts) - e_true).max()
    t_id = time.perf_counter()
    res0 = identify(simulate_sweeps(truth, noise_um=args.noise_um, seed=0), m)
    t_id = time.perf_counter() - t_id
    rms0, max0 = err_stats(ChainField(m, res0.elements_).predict(pts) - e_true)
    cond = res0.condition
    rmss, maxs, sq = [], [], np.zeros(len(pts))
    per_elem = []
    bar = Progress(args.draws, "Monte Carlo noise draws")
    for k in range(1, args.draws + 1):
        r = identify(simulate_sweeps(truth, noise_um=args.noise_um, seed=k), m)
        d = ChainField(m, r.elements_).predict(pts) - e_true
        a, b = err_stats(d)
        rmss.append(a)
        maxs.append(b)
        sq += np.sum(d**2, axis=1)
        per_elem.append(r.elements_.constants["s_xz"])
        bar.update()
    rmss, maxs = np.array(rmss), np.array(maxs)
    prop_rms = float(np.sqrt(np.mean(sq / args.draws)))
    pct = lambda a: f"{np.mean(a):.2f} (5–95 %: {np.percentile(a, 5):.2f}–{np.percentile(a, 95):.2f})"  # noqa: E731
    lines = [
        "# Identification benchmark (laser-tracker sweeps → 23 elements)",
        "",
        f"`python benchmarks/bench_identification.py --draws {args.draws}` on {platform.machine()} "
        f"({platform.python_version()}), {time.strftime('%Y-%m-%d')}. Truth: `random_truth(builtin grinder, seed 3)` "
        f"(max spatial error over the volume ≈ 0.17–0.22 mm); 21 stations per axis; errors evaluated at 10,000 random "
        "axis points (seed 2024). Quantity: the MODEL residual, identified HTM field minus truth field, ‖Δe‖ (μm, vector norm).",
        "",
        "## Noise-free sweeps",
        "",
        "| gauge | max ‖Δe‖ (μm) | target |",
        "|---|---|---|",
    ] + [f"| {g} | {v:.2e} | < 0.01 |" for g, v in free.items()] + [
        "",
        f"## σ = {args.noise_um} μm tracker noise",
        "",
        f"One identification takes {t_id * 1e3:.0f} ms. Gauss-Newton's column-scaled condition: {cond:.3g}.",
        "",
        "| | RMS ‖Δe‖ (μm) | max ‖Δe‖ (μm) |",
        "|---|---|---|",
        f"| noise seed 0 (the reference run) | {rms0:.2f} | {max0:.2f} |",
        f"| Monte Carlo, {args.draws} draws: mean (5–95 %) | {pct(rmss)} | {pct(maxs)} |",
        f"| propagated, sqrt(mean over points and draws of ‖Δe‖²) | {prop_rms:.2f} | — |",
        "",
        f"Reference run vs the spread: RMS at the {100 * np.mean(rmss < rms0):.0f}th percentile, max at the "
        f"{100 * np.mean(maxs < max0):.0f}th: the prediction error is what the tracker noise "
        "propagates to, not a modelling error (noise-free it is below 1e-8 μm). The noise is amplified because the "
        "three balls span only ~100 mm: 2 μm on a ball is ~20–30 μrad on a body's angles, and the angles act on "
        "lever arms of 200–400 mm to the tool point; the angular elements carry most of it. "
        f"Squareness s_xz over the draws: mean {np.mean(per_elem):.1f} μrad, std {np.std(per_elem):.2f} μrad.",
        "",
        f"Total benchmark time {time.perf_counter() - t0:.1f} s.",
    ]
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
