"""Benchmark (issue 26 point 3): the grinder's solvers and G-code path lengths on its chain, beside
main's hand-written kinematics, same invocation.

Every case runs in fresh child processes, one per code checkout (this one and ``--baseline-root``,
e.g. ``git archive`` of main before this work unpacked under /tmp), one after the other; each child
warms up (kernels compiled / loaded), then times ``--repeats`` runs (CPU = ``time.process_time``,
median). The outputs of the two checkouts are compared element by element:

* ``exact``: :func:`compensation.solvers.exact.solve_exact` on ``--exact-points`` targets at seeded random
  axes inside the grinder's strokes, the HTM field of ``random_truth(grinder, seed)``;
* ``exact-chain``: :func:`compensation.solvers.chain_exact.solve_exact_chain` on ``mill-xyz`` and
  ``five-axis-ac`` (seeded smooth element sets, ±20 μm / μrad; rotary axes kept);
* ``batched-ga fused``: :func:`compensation.solvers.batched_ga.solve_batched_ga` with the learned
  field's fused float32 fitness (``training.ga_fitness``; the paper's network fitted to the HTM
  field by ``--train-iters`` LM iterations, trained once, loaded by both), one worker, on
  ``--fused-points`` points spread evenly along the flute path (all 2,800 by default);
* ``batched-ga generic``: the same on the HTM field (``fused=False``) on ``--ga-points`` points;
* ``path lengths``: :func:`compensation.gcode_kernels.linear_path_lengths_mm` of ``--moves``
  seeded linear moves (16 chords each).

Reported per case: CPU s of each checkout (median; each run), the ratio new/main, the largest
difference of the outputs (commands μm or lengths mm), whether the same points succeeded, and
the largest MODEL residual (each solver against its own field) of the solved points.

    nice -n 10 python benchmarks/bench_grinder_chain.py --baseline-root /tmp/main0485
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CASES = ("exact", "exact-chain mill-xyz", "exact-chain five-axis-ac", "batched-ga fused", "batched-ga generic",
         "path lengths")


def _flute(machine, n=None):
    from compensation.toolpath import flute_path
    fp = flute_path()
    t, a = fp.targets_mm, fp.axes(machine)
    if n is not None:
        idx = np.linspace(0, len(t) - 1, n).round().astype(int)
        t, a = t[idx], a[idx]
    return t, a


def child(case, args, out_npz) -> dict:
    """One case with the code on PYTHONPATH; saves the outputs, returns the CPU seconds."""
    from errormap.machine import load_machine
    seed = args.seed
    rng = np.random.default_rng(seed)
    g = load_machine()
    if case == "exact":
        from compensation.solvers.exact import solve_exact
        from errormap.htm import HTMField
        from errormap.kinematics import forward
        from errormap.simulator import random_truth
        f = HTMField(g, random_truth(g, seed).elements)
        ax = rng.uniform(g.stroke_lo, g.stroke_hi, (args.exact_points, 3))
        tg = forward(g, ax)

        def run(k=None):
            return solve_exact(f, tg[:k], g, target_axes=ax[:k], progress=False)
    elif case.startswith("exact-chain"):
        sys.path.insert(0, str(HERE))
        from bench_mt_solve import chain_elements
        from compensation.solvers.chain_exact import solve_exact_chain
        from errormap.mt_field import ChainField
        mt = load_machine(case.split()[1])
        f = ChainField(mt, chain_elements(mt, seed))
        ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (args.points, len(mt.axes)))
        tg = mt.nominal(ax)

        def run(k=None):
            return solve_exact_chain(f, tg[:k], mt, target_axes=ax[:k], progress=False)
    elif case.startswith("batched-ga"):
        from compensation.solvers.batched_ga import solve_batched_ga
        if case.endswith("fused"):
            from training.model import MLPField
            f, fused = MLPField.load(args.model), True
            tg, ax = _flute(g, args.fused_points or None)
        else:
            from errormap.htm import HTMField
            from errormap.simulator import random_truth
            f, fused = HTMField(g, random_truth(g, seed).elements), False
            tg, ax = _flute(g, args.ga_points)

        def run(k=None):
            return solve_batched_ga(f, tg[:k], g, target_axes=ax[:k], seed=seed, workers=1, fused=fused,
                                    progress=False)
    else:
        from compensation.gcode_kernels import linear_path_lengths_mm
        s = rng.uniform(g.stroke_lo, g.stroke_hi, (args.moves, 3))
        s[:, 2] = rng.uniform(-720.0, 720.0, args.moves)
        e = s + rng.normal(0.0, [1.0, 0.5, 20.0], (args.moves, 3))

        def run(k=None):
            return linear_path_lengths_mm(g, s[:k], e[:k])
    run(200)  # warm-up
    cpu = []
    for _ in range(args.repeats):
        c0 = time.process_time()
        r = run()
        cpu.append(time.process_time() - c0)
    if isinstance(r, np.ndarray):
        np.savez(out_npz, out=r)
    else:
        np.savez(out_npz, out=r.commands_mm * 1e3, success=r.success, residual=r.residual_norm_um)
    return {"cpu": cpu}


def _run(root, case, args, out_npz) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # one core each
    cmd = [sys.executable, str(Path(__file__).resolve()), "--_child", case, str(out_npz), "--points", str(args.points),
           "--exact-points", str(args.exact_points), "--moves", str(args.moves), "--ga-points", str(args.ga_points), "--fused-points", str(args.fused_points),
           "--repeats", str(args.repeats),
           "--seed", str(args.seed), "--model", str(args.model)]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{case} on {root} exited {p.returncode}: {p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline-root", required=False, help="a checkout of main before this work")
    ap.add_argument("--points", type=int, default=100_000, help="exact-chain solver targets")
    ap.add_argument("--exact-points", type=int, default=1_000_000, help="grinder exact solver targets")
    ap.add_argument("--moves", type=int, default=1_000_000, help="path-length moves")
    ap.add_argument("--ga-points", type=int, default=280, help="batched-ga points on the HTM field")
    ap.add_argument("--fused-points", type=int, default=0, help="batched-ga fused points (0: the whole flute path)")
    ap.add_argument("--train-iters", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--model", default="", help=argparse.SUPPRESS)
    ap.add_argument("--_child", nargs=2, metavar=("CASE", "NPZ"), help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(HERE / "grinder_chain_results.md"))
    args = ap.parse_args()
    if args._child:
        print(json.dumps(child(args._child[0], args, args._child[1])))
        return
    if not args.baseline_root:
        ap.error("--baseline-root is required (a checkout of main before this work)")
    from errormap.io import atomic_write
    from errormap.machine import load_machine
    from errormap.simulator import random_truth
    sys.path.insert(0, str(HERE))
    from bench_scale_io import _learned_model
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    load0 = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        el = Path(tmp) / "elements.json"
        random_truth(load_machine(), args.seed).elements.save(el)
        if any(c.endswith("fused") for c in cases):
            args.model, _ = _learned_model(tmp, el, args.train_iters)
        for case in cases:
            res = {}
            for code, root in (("main", args.baseline_root), ("new", HERE.parent)):
                npz = Path(tmp) / f"{code}.npz"
                res[code] = (_run(root, case, args, npz), dict(np.load(npz)))
            (rm, om), (rn, on) = res["main"], res["new"]
            cm, cn = float(np.median(rm["cpu"])), float(np.median(rn["cpu"]))
            diff = float(np.abs(om["out"] - on["out"]).max())
            if "success" in om:
                same = "yes" if np.array_equal(om["success"], on["success"]) else "NO"
                solved = f"{int(on['success'].sum()):,}/{len(on['success']):,}"
                resid = f"{om['residual'][om['success']].max():.2e} / {on['residual'][on['success']].max():.2e}"
                unit = "μm"
            else:
                same, solved, resid, unit = "—", "—", "—", "mm"
            n = len(on["out"])
            rows.append(f"| {case} | {n:,} | {cm:.3f} | {cn:.3f} | {cn / cm:.2f} | {diff:.2e} {unit} | {same} | {solved} "
                        f"| {resid} | {', '.join(f'{c:.3f}' for c in rm['cpu'])} | {', '.join(f'{c:.3f}' for c in rn['cpu'])} |")
            print(rows[-1], flush=True)
    load1 = os.getloadavg()
    lines = ["## The grinder's solvers and path lengths on its chain, beside main's hand-written kinematics "
             "(issue 26 point 3)", "",
             f"`nice -n 10 python benchmarks/bench_grinder_chain.py --baseline-root MAIN_CHECKOUT --points {args.points} --exact-points {args.exact_points} "
             f"--moves {args.moves} --ga-points {args.ga_points} --fused-points {args.fused_points} --train-iters {args.train_iters} --repeats "
             f"{args.repeats} --seed {args.seed}` on this machine ({os.cpu_count()} cores, shared; load average "
             f"{load0[0]:.1f} at the start, {load1[0]:.1f} at the end). MAIN_CHECKOUT: main before this work "
             "(`git archive 0485cf2`). Each case: a fresh process per checkout, one after the other, warmed up, "
             f"then {args.repeats} timed runs (one thread: OMP_NUM_THREADS=1; CPU = `time.process_time`, median; each run's in the last columns). "
             "Outputs compared element by element: commands (μm) of the solvers, lengths (mm) of the path "
             "kernel. Residuals are MODEL residuals (each solver against its own field), max over the solved "
             "points. exact: random axes in the grinder's strokes, HTM field of `random_truth(grinder, seed)`; "
             "exact-chain: seeded smooth ChainField (±20 μm / μrad), rotary axes kept; batched-ga fused: the "
             f"paper's network fitted by {args.train_iters} LM iterations to that HTM field, on "
             f"{args.fused_points or 'all 2,800'} evenly spread flute points, one worker; batched-ga generic: the HTM field on {args.ga_points} flute points; "
             "path lengths: seeded linear moves (A over ±2 turns), 16 chords each.", "",
             "| case | points / moves | main CPU (s) | new CPU (s) | new / main | max difference | same points "
             "succeeded | solved (new) | max model residual main / new (μm) | main CPU s of each run | new CPU s of each "
             "run |",
             "|---|---|---|---|---|---|---|---|---|---|---|", *rows, ""]
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
