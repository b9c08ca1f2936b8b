"""Benchmark : the grinder's solvers and G-code path lengths on its chain, beside
main's hand-written kinematics, same invocation.

Every case runs in fresh child processes, one per code checkout (this one and ``--baseline-root``,
e.g. ``git archive`` of main before this work unpacked under /tmp), one after the other; each child
warms up (kernels compiled / loaded), then times ``--repeats`` runs (CPU = ``time.process_time``,
median). The outputs of the two checkouts are compared element by element:

* ``exact``: ``solve("exact", …)`` (the grinder on its chain) on ``--exact-points`` targets at seeded random
  axes inside the grinder's strokes, the HTM field of ``random_truth(grinder, seed)``;
* ``exact-chain``: :func:`compensation.solvers.chain_exact.solve_exact_chain` on ``mill-xyz`` and
  ``five-axis-ac`` (seeded smooth element sets, ±20 μm / μrad; rotary axes kept);
* ``batched-ga fused``: ``solve("batched-ga", …)`` (the grinder on its chain; the fused fitness is no longer used) with the learned
  field's fused float32 fitness (``training.ga_fitness``; the paper's network fitted to the HTM
  field by ``--train-iters`` LM iterations, trained once, loaded by both), one worker, on
  ``--fused-points`` points spread evenly along the flute path (all 2,800 by default);
* ``batched-ga generic``: the same on the HTM field (``fused=False``) on ``--ga-points`` points;
* ``path lengths``: :func:`compensation.gcode_kernels.linear_path_lengths_mm` of ``--moves``
  seeded linear moves (16 chords each);
* ``field+jac MACHINE`` (``grinder``, ``mill-xyz``, ``five-axis-ac``): the field's
  value and axis Jacobian in one pass (``predict_and_jacobian``) at ``--field-points`` seeded axes
  in the strokes (rotary axes over ±2 turns); the grinder's HTM field of ``random_truth``, the
  chains' ChainField of the seeded smooth element sets; reported in μs per point;
* ``exact tight``: the grinder's exact solver on the first ``--tight-points`` targets of ``exact``
  with the default stopping rule and with a tighter one (``--tight-ulps`` ulps of the target's
  largest coordinate and ``|F| ≤ --tight-xtol-um``), alternating, both timed; the main checkout has
  no setting, its module constant ``ROUNDOFF_ULPS`` is set in its child process (benchmark only),
  the new code takes ``roundoff_ulps``. The commands of the two checkouts under the tighter rule
  are compared: two exact solvers that stop anywhere inside the default 1,024 ulps cannot agree
  below that (~5e-8 μm), under the same tighter rule they can.

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
         "path lengths", "field+jac grinder", "field+jac mill-xyz", "field+jac five-axis-ac", "exact tight")


def _flute(machine, n=None):
    from compensation.toolpath import flute_path
    fp = flute_path()
    t, a = fp.targets_mm, fp.axes(machine)
    if n is not None:
        idx = np.linspace(0, len(t) - 1, n).round().astype(int)
        t, a = t[idx], a[idx]
    return t, a


def _chain_elements(mt, seed, scale_um=20.0, n_stations=11):
    """The seeded smooth element set of ``bench_mt_solve`` (``ChainElementSet.random``), written out
    so that main's checkout, which predates that constructor, builds the same numbers."""
    from errormap.chain_elements import ChainElementSet
    rng = np.random.default_rng(seed)
    z = ChainElementSet.zeros(mt, n_stations)
    fun = {}
    for s in mt.slots:
        if s.is_function:
            f = rng.normal(0.0, scale_um, n_stations)
            if next(a for a in mt.axes if a.word == s.axis).full_turn:
                f[-1] = f[0]
            fun[s.name] = f
    return ChainElementSet(mt, z.stations, fun, {k: rng.normal(0.0, scale_um) for k in mt.constant_slots})


def child(case, args, out_npz) -> dict:
    """One case with the code on PYTHONPATH; saves the outputs, returns the CPU seconds."""
    from errormap.machine import load_machine
    seed = args.seed
    rng = np.random.default_rng(seed)
    g = load_machine()
    if case.startswith("field+jac"):
        name = case.split()[1]
        if name == "grinder":
            from errormap.chain_field import ChainField
            from errormap.simulator import random_truth
            mt, f = g, ChainField(g, random_truth(g, seed).elements)
            ax = rng.uniform(g.stroke_lo, g.stroke_hi, (args.field_points, 3))
            ax[:, 2] = rng.uniform(-720.0, 720.0, args.field_points)
        else:
            from errormap.chain_field import ChainField
            mt = load_machine(name)
            f = ChainField(mt, _chain_elements(mt, seed))
            ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (args.field_points, len(mt.axes)))
            for j, a in enumerate(mt.axes):
                if a.full_turn:
                    ax[:, j] = rng.uniform(-720.0, 720.0, args.field_points)

        def run(k=None):
            return f.predict_and_jacobian(ax[:k])
    elif case == "exact tight":
        import inspect

        import compensation.solvers.exact as exact_module
        from errormap.chain_field import ChainField
        from errormap.chain_kernel import forward
        from errormap.simulator import random_truth
        f = ChainField(g, random_truth(g, seed).elements)
        ax = rng.uniform(g.stroke_lo, g.stroke_hi, (args.exact_points, 3))[:args.tight_points]
        tg = forward(g, ax)
        from compensation.solvers import solver_spec
        has_setting = "roundoff_ulps" in solver_spec("exact").options()
        default_ulps = exact_module.ROUNDOFF_ULPS

        def solve(k, tight):
            kw = {"xtol_um": args.tight_xtol_um} if tight else {}
            ulps = args.tight_ulps if tight else default_ulps
            if has_setting:
                kw["roundoff_ulps"] = ulps
            else:
                exact_module.ROUNDOFF_ULPS = ulps  # main's code has no setting: its constant, this process only
            from compensation.solvers import solve as solve_method
            return solve_method("exact", f, tg[:k], g, target_axes=ax[:k], progress=False, **kw)

        solve(200, False), solve(200, True)  # warm-up
        cpu, cpu_default = [], []
        for _ in range(args.repeats):
            c0 = time.process_time()
            r0 = solve(None, False)
            cpu_default.append(time.process_time() - c0)
            c0 = time.process_time()
            r = solve(None, True)
            cpu.append(time.process_time() - c0)
        np.savez(out_npz, out=r.commands_mm * 1e3, success=r.success, residual=r.residual_norm_um,
                 default_out=r0.commands_mm * 1e3, default_residual=r0.residual_norm_um, default_success=r0.success,
                 nfev=r.nfev, default_nfev=r0.nfev)
        return {"cpu": cpu, "cpu_default": cpu_default, "has_setting": has_setting}
    elif case == "exact":
        from functools import partial

        from compensation.solvers import solve as solve_method
        solve_exact = partial(solve_method, "exact")  # the grinder on its chain
        from errormap.chain_field import ChainField
        from errormap.chain_kernel import forward
        from errormap.simulator import random_truth
        f = ChainField(g, random_truth(g, seed).elements)
        ax = rng.uniform(g.stroke_lo, g.stroke_hi, (args.exact_points, 3))
        tg = forward(g, ax)

        def run(k=None):
            return solve_exact(f, tg[:k], g, target_axes=ax[:k], progress=False)
    elif case.startswith("exact-chain"):
        from compensation.solvers.chain_exact import solve_exact_chain
        from errormap.chain_field import ChainField
        mt = load_machine(case.split()[1])
        f = ChainField(mt, _chain_elements(mt, seed))
        ax = rng.uniform(mt.stroke_lo, mt.stroke_hi, (args.points, len(mt.axes)))
        tg = mt.nominal(ax)

        def run(k=None):
            return solve_exact_chain(f, tg[:k], mt, target_axes=ax[:k], progress=False)
    elif case.startswith("batched-ga"):
        from functools import partial

        from compensation.solvers import solve as solve_method
        solve_batched_ga = partial(solve_method, "batched-ga")  # the grinder on its chain
        if case.endswith("fused"):
            from training.model import MLPField
            f, fused = MLPField.load(args.model), True
            tg, ax = _flute(g, args.fused_points or None)
        else:
            from errormap.chain_field import ChainField
            from errormap.simulator import random_truth
            f, fused = ChainField(g, random_truth(g, seed).elements), False
            tg, ax = _flute(g, args.ga_points)

        def run(k=None):
            return solve_batched_ga(f, tg[:k], g, target_axes=ax[:k], seed=seed, progress=False)
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
    if isinstance(r, tuple):  # field value (n, 3) μm and axis Jacobian (n, 3, k)
        np.savez(out_npz, out=r[0], jac=r[1])
    elif isinstance(r, np.ndarray):
        np.savez(out_npz, out=r)
    else:
        np.savez(out_npz, out=r.commands_mm * 1e3, success=r.success, residual=r.residual_norm_um)
    return {"cpu": cpu}


def _run(root, case, args, out_npz) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # one core each
    cmd = [sys.executable, str(Path(__file__).resolve()), "--_child", case, str(out_npz), "--points", str(args.points),
           "--exact-points", str(args.exact_points), "--moves", str(args.moves), "--ga-points", str(args.ga_points), "--fused-points", str(args.fused_points),
           "--field-points", str(args.field_points), "--tight-points", str(args.tight_points),
           "--tight-ulps", repr(args.tight_ulps), "--tight-xtol-um", repr(args.tight_xtol_um),
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
    ap.add_argument("--field-points", type=int, default=1_000_000, help="field value + Jacobian points")
    ap.add_argument("--tight-points", type=int, default=100_000, help="exact solver targets under the tighter stop")
    ap.add_argument("--tight-ulps", type=float, default=16.0, help="tighter stop: ulps of the target's coordinates")
    ap.add_argument("--tight-xtol-um", type=float, default=1e-10, help="tighter stop: |F| in μm")
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
    rows, field_rows, tight_rows, got = [], [], [], {}
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
            n = len(on["out"])
            got[case] = (cm, cn, n)
            runs = f"{', '.join(f'{c:.3f}' for c in rm['cpu'])} | {', '.join(f'{c:.3f}' for c in rn['cpu'])}"
            if case.startswith("field+jac"):
                jd = float(np.abs(om["jac"] - on["jac"]).max())
                field_rows.append(f"| {case.split()[1]} | {n:,} | {cm:.3f} | {cn:.3f} | {cm / n * 1e6:.3f} | {cn / n * 1e6:.3f} "
                                  f"| {cn / cm:.2f} | {diff:.2e} μm | {jd:.2e} | {runs} |")
                print(field_rows[-1], flush=True)
                continue
            if case == "exact tight":
                cdm, cdn = float(np.median(rm["cpu_default"])), float(np.median(rn["cpu_default"]))
                ok = om["success"] & on["success"]
                d_default = float(np.abs(om["default_out"] - on["default_out"])[ok].max())
                d_tight = float(np.abs(om["out"] - on["out"])[ok].max())
                same = "yes" if np.array_equal(om["success"], on["success"]) else "NO"
                tight_rows.append(
                    f"| {n:,} | {d_default:.2e} | {d_tight:.2e} | {same} | {cdm:.3f} / {cm:.3f} ({cm / cdm:.2f}×) "
                    f"| {cdn:.3f} / {cn:.3f} ({cn / cdn:.2f}×) | {int(on['default_nfev']):,} / {int(on['nfev']):,} "
                    f"| {om['default_residual'][ok].max():.2e} / {on['default_residual'][ok].max():.2e} "
                    f"| {om['residual'][ok].max():.2e} / {on['residual'][ok].max():.2e} "
                    f"| {', '.join(f'{c:.3f}' for c in rn['cpu_default'])} | {', '.join(f'{c:.3f}' for c in rn['cpu'])} |")
                print(tight_rows[-1], flush=True)
                continue
            if "success" in om:
                same = "yes" if np.array_equal(om["success"], on["success"]) else "NO"
                solved = f"{int(on['success'].sum()):,}/{len(on['success']):,}"
                resid = f"{om['residual'][om['success']].max():.2e} / {on['residual'][on['success']].max():.2e}"
                unit = "μm"
            else:
                same, solved, resid, unit = "—", "—", "—", "mm"
            rows.append(f"| {case} | {n:,} | {cm:.3f} | {cn:.3f} | {cn / cm:.2f} | {diff:.2e} {unit} | {same} | {solved} "
                        f"| {resid} | {runs} |")
            print(rows[-1], flush=True)
    load1 = os.getloadavg()
    lines = ["## The grinder's solvers and path lengths on its chain, beside main's hand-written kinematics "
             "(issue 26 point 3)", "",
             f"`nice -n 10 python benchmarks/bench_grinder_chain.py --baseline-root MAIN_CHECKOUT --points {args.points} --exact-points {args.exact_points} "
             f"--moves {args.moves} --ga-points {args.ga_points} --fused-points {args.fused_points} --field-points {args.field_points} "
             f"--tight-points {args.tight_points} --tight-ulps {args.tight_ulps:g} --tight-xtol-um {args.tight_xtol_um:g} "
             f"--train-iters {args.train_iters} --repeats "
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
    if field_rows or any(c in got for c in ("exact", "exact-chain mill-xyz", "exact-chain five-axis-ac")):
        lines += ["### field value + Jacobian and the exact solve, beside main's kernels (same run)", "",
                  f"Field value + axis Jacobian in one pass (`predict_and_jacobian`) at {args.field_points:,} seeded "
                  "axes in the strokes (rotary axes over ±2 turns): the grinder's HTM field of `random_truth`, the "
                  "chains' ChainField of the seeded smooth element sets. Goal: ≤ 3 μs a point, within 1.5× of main. "
                  "Max difference: values (μm) and Jacobians (μm per mm / per deg) of the two checkouts.", "",
                  "| machine | points | main CPU (s) | new CPU (s) | main μs/pt | new μs/pt | new / main | max difference "
                  "value | max difference Jacobian | main CPU s of each run | new CPU s of each run |",
                  "|---|---|---|---|---|---|---|---|---|---|---|", *field_rows, ""]
        summary = []
        for name, field_case, solve_case in (("grinder", "field+jac grinder", "exact"),
                                             ("mill-xyz", "field+jac mill-xyz", "exact-chain mill-xyz"),
                                             ("five-axis-ac", "field+jac five-axis-ac", "exact-chain five-axis-ac")):
            fj = got.get(field_case)
            ex = got.get(solve_case)
            fj_s = f"{fj[0] / fj[2] * 1e6:.3f} / {fj[1] / fj[2] * 1e6:.3f}" if fj else "—"
            ex_s = f"{ex[0]:.3f} / {ex[1]:.3f} ({ex[2]:,} points)" if ex else "—"
            summary.append(f"| {name} | {fj_s} | {ex_s} |")
        lines += ["| machine | field value + Jacobian μs/pt, main / new (goal ≤ 3) | exact solve CPU s, main / new "
                  "(goal ≤ 8 s for 1,000,000) |", "|---|---|---|", *summary, ""]
    if tight_rows:
        lines += ["### The exact solver against main's under the same tighter stopping rule", "",
                  f"The grinder's exact solver on the first {args.tight_points:,} targets of `exact`, each checkout "
                  f"with its default stop (|F| ≤ 1e-9 μm or within 1,024 ulps of the target's largest coordinate) "
                  f"and with a tighter one: |F| ≤ {args.tight_xtol_um:g} μm or within {args.tight_ulps:g} ulps "
                  "(main has no setting: its module constant is set in its own child process, benchmark only; the "
                  "new code's `solve_exact(roundoff_ulps=…, xtol_um=…)`). Alternating default and tight runs, "
                  f"{args.repeats} each, CPU median. Differences and MODEL residuals (μm) over the points both "
                  "solved.", "",
                  "| points | max difference, default stop (μm) | max difference, tight stop (μm) | same points "
                  "succeeded | main CPU s default / tight | new CPU s default / tight | new field evaluations "
                  "default / tight | max model residual default, main / new (μm) | max model residual tight, main "
                  "/ new (μm) | new CPU s of each default run | new CPU s of each tight run |",
                  "|---|---|---|---|---|---|---|---|---|---|---|", *tight_rows, ""]
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
