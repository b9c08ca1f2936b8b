"""Benchmark : the exact HTM field, reference vs fast, side by side in one run.

* field: μs per point of ``HTMField.predict`` (exact) — the reference pipeline (18 per-element
  splines + the (n, 3, 3) numpy matrix chain (``MachineTool.spatial_error``); the baseline's
  hand-written one with ``--baseline-root``) against the fast one (3 vector-valued per-axis splines
  + the compiled chain, ``HTMField.predict``);
* field + Jacobian: μs per point of ``HTMField.predict_and_jacobian`` (exact, one pass);
* solve: μs per point of ``solve_exact`` on the same targets with either field — the reference
  declares no Jacobian (the solver differentiates it by forward differences, 3 more evaluations
  per point), the fast one its closed-form Jacobian — and the largest difference of the commands
  (μm) between the two. Both solves run the current solver; the solver before the fast field is timed
  against this one in ``bench_solve_scale.py`` (``--baseline-root``).

Points: uniform over the strokes with A over several turns, truth ``random_truth(seed)``.
Each seed is one job (``--jobs`` processes); per seed the median of ``--repeats`` runs.
Since issue 26 point 3 the fast field is the grinder's chain file through the generic compiled
kernel (errormap/chain_kernel.py); with ``--baseline-root DIR`` (a copy of main before that change,
imported beside this checkout by benchmarks/baseline.py) the hand-written closed-form kernel it
replaced is timed in the same process (field and field + J) with the ratio and the largest
differences.
Run: python benchmarks/bench_htm_field.py [--points N] [--seeds S] [--jobs J] [--repeats R] [--baseline-root DIR]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from errormap.elements import AXIS_OF, CONSTANT_ELEMENTS, FUNCTION_ELEMENTS
from errormap.chain_field import ChainField
from errormap.io import atomic_write
from errormap.chain_kernel import forward
from errormap.machine import load_machine
from errormap.simulator import random_axes, random_truth


def _numpy_chain(machine, axes, values, chunk):
    """The chain file's numpy reference (:meth:`errormap.machine_tool.MachineTool.spatial_error`)."""
    return machine.spatial_error(axes, values, chunk=min(chunk, 4096))


class ReferenceChainField(ChainField):
    """The exact HTM field as it was before the fast field: per-element splines, matrix chain, no Jacobian.

    ``exact_chain(machine, axes, values, chunk)`` is the numpy matrix chain: the hand-written one of
    the baseline (``--baseline-root``, the pipeline this column timed before the chain kernel replaced it) or,
    without a baseline, the chain file's numpy reference (:func:`_numpy_chain`)."""

    capabilities = frozenset()

    def __init__(self, machine, elements, exact_chain=_numpy_chain):
        super().__init__(machine, elements)
        self.grinder_elements = elements
        self.exact_chain = exact_chain
        from scipy.interpolate import make_interp_spline   # one spline per element, the per-element reference
        self.splines = {k: make_interp_spline(elements.stations[AXIS_OF[k]], elements.functions[k], k=3,
                                              bc_type="periodic" if AXIS_OF[k] == "a_deg" else None)
                        for k in FUNCTION_ELEMENTS}

    def predict(self, axes):
        axes = np.asarray(axes, dtype=float)
        el = self.grinder_elements
        cols = {"x_mm": axes[:, 0], "z_mm": axes[:, 1], "a_deg": el.wrap("a_deg", axes[:, 2])}
        v = np.stack([self.splines[k](cols[AXIS_OF[k]]) for k in FUNCTION_ELEMENTS]
                     + [np.full(len(axes), el.constants[k]) for k in CONSTANT_ELEMENTS], axis=1)
        return self.exact_chain(self.machine, axes, v, chunk=self.chunk)


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return statistics.median(times), out


def run_seed(seed, points, repeats, solve_points, baseline_root=None):
    from functools import partial

    from compensation.solvers import solve as solve_method
    solve_exact = partial(solve_method, "exact")  # the grinder on its chain
    m = load_machine()
    el = random_truth(m, seed).elements
    rng = np.random.default_rng([seed, 20])
    axes = random_axes(m, points, rng)
    axes[:, 2] += 360.0 * rng.integers(-3, 4, points)
    old_htm = None
    if baseline_root:
        from baseline import baseline_module
        old_htm = baseline_module(baseline_root, "htm")
    ref = ReferenceChainField(m, el, old_htm.spatial_error_exact_chain if old_htm else _numpy_chain)
    new = ChainField(m, el)
    new.predict(axes[:10]), ref.predict(axes[:10])  # compile / build splines outside the timing
    t_ref, e_ref = _median_time(lambda: ref.predict(axes), repeats)
    t_new, e_new = _median_time(lambda: new.predict(axes), repeats)
    t_jac, (_, j_new) = _median_time(lambda: new.predict_and_jacobian(axes), repeats)
    old = {}
    if old_htm is not None:
        hand = old_htm.ChainField(m, el)
        hand.predict(axes[:10]), hand.predict_and_jacobian(axes[:10])
        t_hv, e_h = _median_time(lambda: hand.predict(axes), repeats)
        t_hj, (_, j_h) = _median_time(lambda: hand.predict_and_jacobian(axes), repeats)
        old = {"hand_us": t_hv / points * 1e6, "hand_jac_us": t_hj / points * 1e6,
               "hand_diff_um": float(np.abs(e_new - e_h).max()), "hand_diff_jac": float(np.abs(j_new - j_h).max())}
    targets = forward(m, axes[:solve_points])
    s_ref, r_ref = _median_time(lambda: solve_exact(ref, targets, m, progress=False), repeats)
    s_new, r_new = _median_time(lambda: solve_exact(new, targets, m, progress=False), repeats)
    return {"seed": seed, "field_ref_us": t_ref / points * 1e6, "field_new_us": t_new / points * 1e6,
            "field_jac_us": t_jac / points * 1e6,
            "field_diff_um": float(np.abs(e_new - e_ref).max()),
            "solve_ref_us": s_ref / solve_points * 1e6, "solve_new_us": s_new / solve_points * 1e6,
            "commands_diff_um": float(np.abs(r_new.commands_mm - r_ref.commands_mm)[r_new.success & r_ref.success].max() * 1e3),
            "solved": f"{int(r_new.success.sum())}/{solve_points} vs {int(r_ref.success.sum())}/{solve_points}", **old}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--solve-points", type=int, default=50_000)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "htm_field_results.md"))
    ap.add_argument("--baseline-root", default=None,
                    help="a copy of main before the chain kernel replaced it: time its hand-written kernel beside the chain's")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    seeds = list(range(args.seeds))
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_seed, seeds, [args.points] * len(seeds), [args.repeats] * len(seeds),
                             [args.solve_points] * len(seeds), [args.baseline_root] * len(seeds)))
    lines = ["## Fast exact HTM field", "",
             f"`python benchmarks/bench_htm_field.py --points {args.points} --solve-points {args.solve_points} "
             f"--seeds {args.seeds} --jobs {args.jobs} --repeats {args.repeats}"
             + (" --baseline-root MAIN_BEFORE" if args.baseline_root else "") + "` — default grinder, truth "
             "`random_truth(seed)`, points uniform over the strokes with A over -3..+3 extra turns; "
             f"median of {args.repeats} runs per seed (CPU time of the process: the load of the shared cores inflates wall time), reference and fast in the same process, one after the other; "
             f"{os.cpu_count()} cores shared with other work (load average {load0:.1f} at the start, "
             f"{os.getloadavg()[0]:.1f} at the end). Reference = per-element splines + (n, 3, 3) matrix chain "
             "(the field before the fast field; "
             + ("the hand-written numpy chain of the baseline copy of main" if args.baseline_root else
                "the chain file's numpy reference chain, chunks of 4,096 points — slower than the hand-written "
                "numpy chain it replaced, so this speed-up is not comparable with runs before the chain kernel replaced it")
             + "); fast = per-axis vector splines + the grinder's chain file through the "
             "generic compiled kernel (the hand-written closed form before it); field + J = "
             "`predict_and_jacobian` (value and exact geometric Jacobian in one pass). "
             "Solve = `solve_exact` (the current solver, CPU of one thread) on the nominal tool points of the first "
             "solve-points axes (model residual): ref = the reference field without a Jacobian (forward differences), "
             "fast = the fast field with its closed-form Jacobian.", "",
             "| seed | field ref (μs/pt) | field fast (μs/pt) | speed-up | field + J fast (μs/pt) | max |ΔE| (μm) "
             "| solve ref (μs/pt) | solve fast (μs/pt) | speed-up | max |Δcommand| on points both solve (μm) | solved fast vs ref |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['field_ref_us']:.2f} | {r['field_new_us']:.2f} | "
                     f"{r['field_ref_us'] / r['field_new_us']:.1f}× | {r['field_jac_us']:.2f} | {r['field_diff_um']:.1e} | {r['solve_ref_us']:.1f} | "
                     f"{r['solve_new_us']:.1f} | {r['solve_ref_us'] / r['solve_new_us']:.1f}× | "
                     f"{r['commands_diff_um']:.1e} | {r['solved']} |")
    if args.baseline_root:
        lines += ["", "Hand-written closed-form kernel (errormap/htm.py before the chain kernel replaced it, from a copy of main, "
                  "commit 0485cf2) beside the chain kernel, same process, same points:", "",
                  "| seed | field hand (μs/pt) | field chain (μs/pt) | ratio | field + J hand (μs/pt) | "
                  "field + J chain (μs/pt) | ratio | max abs ΔE (μm) | max abs ΔJ (μm per mm/deg) |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| {r['seed']} | {r['hand_us']:.3f} | {r['field_new_us']:.3f} | "
                         f"{r['field_new_us'] / r['hand_us']:.2f}× | {r['hand_jac_us']:.3f} | {r['field_jac_us']:.3f} | "
                         f"{r['field_jac_us'] / r['hand_jac_us']:.2f}× | {r['hand_diff_um']:.1e} | {r['hand_diff_jac']:.1e} |")
    text = "\n".join(lines) + "\n"
    print(text)
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
