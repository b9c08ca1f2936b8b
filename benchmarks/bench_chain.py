"""Benchmark : the generic chain field kernel beside the hand-written grinder kernel.

* grinder: μs per point of the hand-written compiled closed form that ``HTMField`` used before
  issue 26 point 3 (errormap/htm.py of ``--baseline-root``, a copy of main before that change,
  imported beside this checkout by benchmarks/baseline.py: the old kernel is no longer in the
  package), of ``ChainField.predict`` / ``predict_and_jacobian`` on the grinder's chain file
  ``grinder-chain`` (errormap/chain_kernel.py, generic over the compiled op arrays) and of today's
  ``HTMField`` (the same generic kernel, packed once per field); same element values
  (``random_truth(seed)``), same points, in the same process one after the other; the ratio and
  the largest difference of the values (μm) and Jacobians.
* mill-xyz, five-axis-ac, lathe-xzc: μs per point of the generic kernel on random element sets
  (±25 μm / μrad at 21 stations, constants ±25; seeded through ``errormap.seeds``).

CPU time of the process (the shared cores inflate wall time); per seed the median of ``--repeats``.
Points uniform over the strokes, full-turn axes over -3..+3 extra turns.
Run: python benchmarks/bench_chain.py --baseline-root MAIN_BEFORE [--points N] [--seeds S] [--jobs J] [--repeats R]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from baseline import baseline_module
from errormap.chain_field import ChainField
from errormap.io import atomic_write
from errormap.machine import load_machine
from errormap.chain_elements import ChainElementSet
from errormap.seeds import spawn_rngs
from errormap.simulator import random_truth

OTHER_MACHINES = ("mill-xyz", "five-axis-ac", "lathe-xzc")
ELEMENT_SCALE = 25.0  # μm / μrad per station: the size of a machine tool's component errors
GOAL_RATIO = 1.5      # goal: the generic kernel within 1.5× of today's hand-written one
GOAL_US = 3.0         # goal: field value + Jacobian ≤ 3 μs per point
ERROR_JAC_POINTS = 50_000  # the hand-written error-transfer Jacobian is numpy with (n, 3, 23) temporaries


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return statistics.median(times), out


def _axes(mt, n, rng):
    ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (n, len(mt.axes)))
    for j, a in enumerate(mt.axes):
        if a.full_turn:
            ax[:, j] += 360.0 * rng.integers(-3, 4, n)
    return ax


def _random_elements(mt, rng, n_stations=21):
    z = ChainElementSet.zeros(mt, n_stations)
    full = {a.word for a in mt.axes if a.full_turn}
    fun = {}
    for s in mt.slots:
        if s.is_function:
            f = rng.normal(0.0, ELEMENT_SCALE, n_stations)
            if s.axis in full:
                f[-1] = f[0]
            fun[s.name] = f
    return ChainElementSet(mt, z.stations, fun, {k: rng.normal(0.0, ELEMENT_SCALE) for k in mt.constant_slots})


def run_seed(seed, points, repeats, baseline_root):
    old = baseline_module(baseline_root, "htm")
    rng_axes, rng_el = spawn_rngs(seed, 2)
    g, mt = load_machine(), load_machine("grinder-chain")
    el = random_truth(g, seed).elements
    hand, chain, htm = old.ChainField(g, el), ChainField(mt, ChainElementSet(mt, el.stations, el.functions, el.constants)), ChainField(g, el)
    ax = _axes(mt, points, rng_axes)
    for f in (hand, chain, htm):  # compile / build splines outside the timing
        f.predict(ax[:10]), f.predict_and_jacobian(ax[:10])
    t_hv, e_h = _median_time(lambda: hand.predict(ax), repeats)
    t_cv, e_c = _median_time(lambda: chain.predict(ax), repeats)
    t_hj, (_, j_h) = _median_time(lambda: hand.predict_and_jacobian(ax), repeats)
    t_cj, (_, j_c) = _median_time(lambda: chain.predict_and_jacobian(ax), repeats)
    t_nv, e_n = _median_time(lambda: htm.predict(ax), repeats)
    t_nj, (_, j_n) = _median_time(lambda: htm.predict_and_jacobian(ax), repeats)
    ne = min(points, ERROR_JAC_POINTS)
    t_he, je_h = _median_time(lambda: old.error_jacobian(g, ax[:ne]), repeats)
    t_ce, je_c = _median_time(lambda: chain.error_jacobian(ax[:ne]), repeats)
    row = {"seed": seed, "hand_v": t_hv / points * 1e6, "chain_v": t_cv / points * 1e6,
           "hand_j": t_hj / points * 1e6, "chain_j": t_cj / points * 1e6,
           "htm_v": t_nv / points * 1e6, "htm_j": t_nj / points * 1e6,
           "diff_um": float(np.abs(e_c - e_h).max()), "diff_jac": float(np.abs(j_c - j_h).max()),
           "diff_htm_um": float(np.abs(e_n - e_h).max()), "diff_htm_jac": float(np.abs(j_n - j_h).max()),
           "hand_e": t_he / ne * 1e6, "chain_e": t_ce / ne * 1e6, "diff_e": float(np.abs(je_c - je_h).max()),
           "others": {}}
    for name in OTHER_MACHINES:
        m = load_machine(name)
        f = ChainField(m, _random_elements(m, rng_el))
        a = _axes(m, points, rng_axes)
        f.predict(a[:10]), f.predict_and_jacobian(a[:10])
        tv, _ = _median_time(lambda: f.predict(a), repeats)
        tj, _ = _median_time(lambda: f.predict_and_jacobian(a), repeats)
        row["others"][name] = (tv / points * 1e6, tj / points * 1e6, len(m.chain.ets), len(m.slots))
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "chain_results.md"))
    ap.add_argument("--baseline-root", required=True,
                    help="a copy of main before the chain kernel replaced it (its errormap/htm.py has the hand-written kernel)")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    seeds = list(range(args.seeds))
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_seed, seeds, [args.points] * len(seeds), [args.repeats] * len(seeds),
                             [args.baseline_root] * len(seeds)))
    med = {k: statistics.median(r[k] for r in rows) for k in ("hand_v", "chain_v", "hand_j", "chain_j", "hand_e",
                                                               "chain_e", "htm_v", "htm_j")}
    lines = ["## Machine-tool chains compiled once: the generic field kernel", "",
             f"`python benchmarks/bench_chain.py --points {args.points} --seeds {args.seeds} --jobs {args.jobs} "
             f"--repeats {args.repeats} --baseline-root MAIN_BEFORE` — CPU time of the process, median of {args.repeats} runs per seed, "
             f"{os.cpu_count()} cores shared with other work (load average {load0:.1f} at the start, "
             f"{os.getloadavg()[0]:.1f} at the end). Grinder: the hand-written compiled kernel "
             "(`HTMField` of errormap/htm.py before the chain kernel replaced it, imported from a copy of main, commit "
             "0485cf2, by benchmarks/baseline.py) and the generic chain kernel (`ChainField` on `grinder-chain`, "
             "errormap/chain_kernel.py) on the same element values (`random_truth(seed)`) and the same points "
             "(uniform over the strokes, A over -3..+3 extra turns), one after the other. Value = `predict`, "
             "value + J = `predict_and_jacobian` (spatial error and its axis Jacobian in one pass). "
             "Max |ΔE| and max |ΔJ|: largest difference between the two (model residual of the "
             "re-implementation, μm and μm per mm/deg). Today's `HTMField` (the grinder's chain file, packed "
             "once per field) is timed beside them (last columns).", "",
             "| seed | value hand (μs/pt) | value chain (μs/pt) | ratio | value + J hand (μs/pt) | "
             "value + J chain (μs/pt) | ratio | max abs ΔE (μm) | max abs ΔJ | HTMField now: value (μs/pt) | "
             "value + J (μs/pt) | ratio to hand | max abs ΔE (μm) | max abs ΔJ |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['hand_v']:.3f} | {r['chain_v']:.3f} | {r['chain_v'] / r['hand_v']:.2f}× | "
                     f"{r['hand_j']:.3f} | {r['chain_j']:.3f} | {r['chain_j'] / r['hand_j']:.2f}× | "
                     f"{r['diff_um']:.1e} | {r['diff_jac']:.1e} | {r['htm_v']:.3f} | {r['htm_j']:.3f} | "
                     f"{r['htm_j'] / r['hand_j']:.2f}× | {r['diff_htm_um']:.1e} | {r['diff_htm_jac']:.1e} |")
    lines.append(f"| median | {med['hand_v']:.3f} | {med['chain_v']:.3f} | {med['chain_v'] / med['hand_v']:.2f}× | "
                 f"{med['hand_j']:.3f} | {med['chain_j']:.3f} | {med['chain_j'] / med['hand_j']:.2f}× | | | "
                 f"{med['htm_v']:.3f} | {med['htm_j']:.3f} | {med['htm_j'] / med['hand_j']:.2f}× | | |")
    worst = max(med["chain_j"], med["htm_j"])
    ok_ratio = worst / med["hand_j"] <= GOAL_RATIO
    ok_us = worst <= GOAL_US
    lines += ["", f"Goal : value + J within {GOAL_RATIO}× of the hand-written kernel — "
              f"{'met' if ok_ratio else 'NOT met'} ({worst / med['hand_j']:.2f}×, the slower of ChainField and "
              f"HTMField); ≤ {GOAL_US:g} μs/point — {'met' if ok_us else 'NOT met'} ({worst:.2f} μs).", "",
              "Error-transfer Jacobian ∂E/∂(elements), (n, 3, 23) — what identification uses: hand-written "
              "`errormap.htm.error_jacobian` of the baseline (numpy) vs the compiled chain form (today's "
              "`errormap.htm.error_jacobian` computes through it) `ChainField.error_jacobian`, "
              f"first {min(args.points, ERROR_JAC_POINTS):,} points, μs/pt (medians over seeds): "
              f"hand {med['hand_e']:.2f}, chain {med['chain_e']:.2f}; largest difference "
              f"{max(r['diff_e'] for r in rows):.1e} μm per μm/μrad.", "",
              "Other built-in chains (generic kernel only; random element sets ±"
              f"{ELEMENT_SCALE:g} μm/μrad; medians over seeds):", "",
              "| machine | ETs in the compiled chain | error slots | value (μs/pt) | value + J (μs/pt) |",
              "|---|---|---|---|---|"]
    for name in OTHER_MACHINES:
        v = statistics.median(r["others"][name][0] for r in rows)
        j = statistics.median(r["others"][name][1] for r in rows)
        n_et, n_sl = rows[0]["others"][name][2:]
        lines.append(f"| {name} | {n_et} | {n_sl} | {v:.3f} | {j:.3f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
