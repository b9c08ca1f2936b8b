"""Benchmark : the solve stage of ``volcomp compensate --method exact`` at scale.

What the command does with a parsed path: ``compensation.batch.solve_batch`` (fixed chunks of
65,536 points on :class:`compensation.batch.LocalExecutor` threads) with the exact solver.
Timed here on ``--points`` targets along the tool path of ``bench_scale_io.gcode_program``
(X sweeping the stroke 0.02 mm a line, Z a slow sine, A 0.05° a line, unwrapped), with

* the element-set (HTM) field of ``random_truth(seed)``,
* a learned field (the paper's network 10-15-25-15-10) fitted to it (``--train-iters`` LM
  iterations on an 11³ grid; timing only, its accuracy is not the subject),

each run a fresh process: this checkout with ``--workers`` threads (default 1 and 2), and with
``--baseline-root DIR`` (a checkout of main before this work) the same run there. Reported:
wall and CPU seconds (user + system, ``os.wait4``) of the solve alone, μs per point, field
evaluations per point, points solved, whether the commands are byte-identical across worker
counts, and the largest difference of the commands (μm) from the baseline on the points both
solve (model residual ≤ 1e-4 μm on either side). The load average is printed before and after
(2 cores shared with other work: CPU time is the steadier figure).

    python benchmarks/bench_solve_scale.py --points 1000000 --baseline-root /path/to/main
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
from types import SimpleNamespace

import numpy as np

HERE = Path(__file__).resolve().parent


def path_axes(n: int, seed: int = 0) -> np.ndarray:
    """Nominal axes (n, 3) of ``bench_scale_io.gcode_program``'s moves (its X/Z/A formulas)."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    period = 8000
    ph = (k % (2 * period)) / period
    x = 20.0 + 160.0 * np.where(ph < 1, ph, 2 - ph)
    z = 30.0 + 20.0 * np.sin(2 * np.pi * k / 50000.0) + rng.uniform(-0.0005, 0.0005, n)
    return np.column_stack([x, z, 0.05 * k])


def child(model_kind: str, model_path: str, points: int, workers: int, seed: int, out_npz: str) -> dict:
    """One solve in this process (the code on PYTHONPATH); returns the figures as a dict."""
    from compensation.batch import LocalExecutor, solve_batch
    from errormap.chain_kernel import forward
    from errormap.machine import load_machine
    m = load_machine()
    if model_kind == "htm":
        from errormap.chain_elements import ChainElementSet
        from errormap.chain_field import ChainField
        field = ChainField(m, ChainElementSet.load(model_path, m))
    else:
        from training.model import MLPField
        field = MLPField.load(model_path)
    axes = path_axes(points, seed)
    targets = forward(m, axes)

    path = SimpleNamespace(targets_mm=targets, axes=axes, path="bench")  # what solve_batch reads of a parsed path
    small = SimpleNamespace(targets_mm=targets[:200], axes=axes[:200], path="warm-up")
    solve_batch("exact", field, m, [small], executor=LocalExecutor(workers))  # compile / warm up
    t0, c0 = time.perf_counter(), time.process_time()
    r = solve_batch("exact", field, m, [path], executor=LocalExecutor(workers))[0]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    np.savez(out_npz, commands=r.commands_mm, success=r.success)
    return {"wall_s": wall, "cpu_s": cpu, "nfev": int(r.nfev), "solved": int(r.success.sum()), "points": points}


def _run(root, model_kind, model_path, points, workers, seed, out_npz, repeats=1) -> dict:
    """``repeats`` fresh processes; the median wall and CPU seconds (the other figures are the same in each)."""
    runs = [_run_once(root, model_kind, model_path, points, workers, seed, out_npz) for _ in range(repeats)]
    out = dict(runs[-1])
    out["wall_s"] = float(np.median([r["wall_s"] for r in runs]))
    out["cpu_s"] = float(np.median([r["cpu_s"] for r in runs]))
    out["cpu_all_s"] = [r["cpu_s"] for r in runs]
    return out


def _run_once(root, model_kind, model_path, points, workers, seed, out_npz) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--_child", model_kind, str(model_path), str(points),
           str(workers), str(seed), str(out_npz)]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{cmd} exited {p.returncode}: {p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--_child":
        kind, path, n, w, seed, out = sys.argv[2:8]
        print(json.dumps(child(kind, path, int(n), int(w), int(seed), out)))
        return
    from bench_scale_io import _learned_model  # the same learned field as the end-to-end G-code benchmark
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--workers", default="1,2", help="thread counts of this checkout's runs")
    ap.add_argument("--baseline-root", default=None, help="another checkout (e.g. main) timed with the most workers")
    ap.add_argument("--train-iters", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=1, help="fresh processes per run; median wall and CPU")
    ap.add_argument("--seeds", type=int, default=1, help="truths random_truth(seed), one after the other")
    ap.add_argument("--jobs", type=int, default=1, help="unused: runs are timed one at a time (shared cores)")
    ap.add_argument("--out", default=str(HERE / "solve_scale_results.md"))
    args = ap.parse_args()
    from errormap.io import atomic_write
    from errormap.machine import load_machine
    from errormap.simulator import random_truth
    here = HERE.parent
    workers = [int(w) for w in args.workers.split(",")]
    load0 = os.getloadavg()
    rows, notes = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            el_path = Path(tmp) / f"elements{seed}.json"
            random_truth(load_machine(), seed).elements.save(el_path)
            learned, val_um = _learned_model(tmp, el_path, args.train_iters)
            notes.append(f"seed {seed}: learned field validation max {val_um:.3g} μm")
            for label, kind, path in (("element set (HTM)", "htm", el_path),
                                      ("learned (paper MLP 10-15-25-15-10)", "mlp", learned)):
                runs = []
                for w in workers:
                    npz = Path(tmp) / f"new_{kind}_{w}.npz"
                    runs.append(("this branch", w, _run(here, kind, path, args.points, w, seed, npz, args.repeats), npz))
                if args.baseline_root:
                    npz = Path(tmp) / f"base_{kind}.npz"
                    runs.append(("main (baseline)", max(workers),
                                 _run(args.baseline_root, kind, path, args.points, max(workers), seed, npz, args.repeats), npz))
                new = [np.load(r[3]) for r in runs if r[0] == "this branch"]
                same = all(np.array_equal(new[0]["commands"], x["commands"]) for x in new[1:])
                for code, w, res, npz in runs:
                    d = "—"
                    if args.baseline_root and code == "this branch":
                        b, a = np.load(runs[-1][3]), np.load(npz)
                        both = a["success"] & b["success"]
                        d = f"{np.abs(a['commands'][both] - b['commands'][both]).max() * 1e3:.1e}"
                    rows.append(f"| {seed} | {label} | {code} | {w} | {res['wall_s']:.2f} | {res['cpu_s']:.2f} | "
                                f"{res['cpu_s'] / res['points'] * 1e6:.2f} | {res['nfev'] / res['points']:.2f} | "
                                f"{res['solved']:,}/{res['points']:,} | {'yes' if same else 'NO'} | {d} | "
                                f"{', '.join(f'{c:.2f}' for c in res['cpu_all_s'])} |")
    load1 = os.getloadavg()
    lines = ["## Solve stage at scale: `compensate --method exact`", "",
             f"`python benchmarks/bench_solve_scale.py --points {args.points} --workers {args.workers}"
             + (" --baseline-root MAIN_CHECKOUT" if args.baseline_root else "")
             + f" --train-iters {args.train_iters} --seeds {args.seeds} --repeats {args.repeats}` on this machine ({os.cpu_count()} cores, "
             f"shared; load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end). Targets: the nominal tool "
             "points of the scale benchmark's G-code path (`bench_scale_io.gcode_program`'s X/Z/A); the solve as the "
             "command runs it (`solve_batch`, chunks of 65,536 points on `--workers` threads of one process), each "
             f"run a fresh process, timed after a 200-point warm-up (compiled kernels loaded); median of {args.repeats} "
             "such runs (the CPU seconds of each in the last column). CPU = user + system "
             "of the process during the solve; on shared cores wall time waits for them, CPU time is the "
             "steadier figure. Model residual: success = |residual| ≤ 1e-4 μm inside the 250 μm ball. "
             "Δ = largest |command difference| from the baseline on points both solve. "
             + "; ".join(notes) + ".", "",
             "| seed | model | code | threads | wall (s) | CPU (s) | CPU μs/pt | field evaluations/pt | solved "
             "| identical across thread counts | max Δ command vs baseline (μm) | CPU s of each run |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"] + rows
    text = "\n".join(lines) + "\n"
    print(text)
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
