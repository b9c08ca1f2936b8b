"""Benchmark (issue 20): batch compensation throughput, in-process vs a local Ray cluster, side by side.

The batch: ``--files`` paths of ``--file-points`` points plus one path of ``--points`` points
(axis points uniform over the strokes, 1 mm / 0.5 mm inside X / Z), an element-set (HTM)
field of ``random_truth(seed)``, ``--method`` (default exact). Each mode solves the whole batch
through :func:`compensation.batch.solve_batch` (the chunk plan every run uses, 65,536 points a
chunk), in one process, alternating, ``--repeats`` times (medians):

* ``serial``: one thread (``--workers 1`` of the local run);
* ``threads``: ``--workers`` threads of this process (the local run's default on this machine);
* ``ray (cold)``: a Ray instance with ``--workers`` CPUs already running, the batch creates its
  actors (each worker process imports numpy/numba/torch and receives the field) and solves;
* ``ray (warm)``: the same actors again (a long-lived cluster's steady state).

The Ray instance's own start (``ray.init``) is timed once. Every mode's commands are checked
equal bit for bit to the serial run's (the chunk plan). Only the solve stage is timed: reading,
guarding and writing happen on the driver and are the same for every mode. The load of the
machine (``uptime``) is recorded before and after.

    python benchmarks/bench_cluster.py --files 8 --file-points 25000 --points 1000000 --workers 2
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from compensation.batch import CHUNK_POINTS, LocalExecutor, solve_batch
from errormap.chain_field import ChainField
from errormap.io import atomic_write, write_json
from errormap.machine import load_machine
from errormap.simulator import random_axes, random_truth
from errormap.chain_kernel import forward

HERE = Path(__file__).resolve().parent


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        return "n/a"


def make_batch(machine, n_files, file_points, big_points, seed):
    rng = np.random.default_rng(seed)
    out = []
    for n in [file_points] * n_files + [big_points]:
        ax = random_axes(machine, n, rng)
        ax[:, 0] = np.clip(ax[:, 0], 1.0, machine.stroke_hi[0] - 1.0)
        ax[:, 1] = np.clip(ax[:, 1], 0.5, machine.stroke_hi[1] - 0.5)
        out.append(SimpleNamespace(targets_mm=forward(machine, ax), axes=ax))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--files", type=int, default=8)
    ap.add_argument("--file-points", type=int, default=25_000)
    ap.add_argument("--points", type=int, default=1_000_000, help="points of the one large path")
    ap.add_argument("--workers", type=int, default=2, help="threads / Ray CPUs (default 2)")
    ap.add_argument("--jobs", type=int, default=None, help="alias of --workers (the benchmarks' usual name)")
    ap.add_argument("--seeds", type=int, default=1, help="truth seeds 0..N-1, one batch each")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--method", default="exact")
    ap.add_argument("--where", default="the shared 2-core development machine")
    ap.add_argument("--out", default=str(HERE / "cluster_results"), help="output stem (.md and .json)")
    args = ap.parse_args()
    workers = args.jobs or args.workers
    import ray

    from compensation.app.workflows.cluster import RayExecutor
    machine = load_machine()
    load_before = uptime()
    os.environ.setdefault("PYTHONPATH", str(HERE.parent))
    t0 = time.perf_counter()
    ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
    ray_start_s = time.perf_counter() - t0
    rows = []
    try:
        for seed in range(args.seeds):
            field = ChainField(machine, random_truth(machine, seed).elements)
            paths = make_batch(machine, args.files, args.file_points, args.points, seed)
            n_points = sum(len(p.axes) for p in paths)
            # warm-up in this process (numba kernels loaded, solver modules imported) before any timing
            solve_batch(args.method, field, machine, make_batch(machine, 1, 100, 100, seed), executor=LocalExecutor(1))
            times = {k: [] for k in ("serial", "threads", "ray (cold)", "ray (warm)")}
            ref = None
            for _ in range(args.repeats):
                for mode in times:
                    if mode == "serial":
                        ex, ctx = LocalExecutor(1), None
                    elif mode == "threads":
                        ex, ctx = LocalExecutor(workers), None
                    else:
                        if mode == "ray (cold)":
                            ctx = RayExecutor()
                            ctx.__enter__()
                        ex = ctx
                    t = time.perf_counter()
                    res = solve_batch(args.method, field, machine, paths, seed=seed, executor=ex, progress=None)
                    times[mode].append(time.perf_counter() - t)
                    if mode == "ray (warm)":
                        ctx.__exit__(None, None, None)
                    cmds = np.concatenate([r.commands_mm for r in res])
                    if ref is None:
                        ref = cmds
                    assert np.array_equal(cmds, ref), f"{mode}: commands differ from the serial run's"
                    print(f"seed {seed} {mode}: {times[mode][-1]:.1f} s", flush=True)
            med = {k: statistics.median(v) for k, v in times.items()}
            rows.append({"seed": seed, "points": n_points, "paths": len(paths), "median_s": med,
                         "equal_bit_for_bit": True})
    finally:
        ray.shutdown()
    load_after = uptime()
    doc = {"method": args.method, "workers": workers, "files": args.files, "file_points": args.file_points,
           "big_points": args.points, "chunk_points": CHUNK_POINTS, "repeats": args.repeats,
           "ray_version": ray.__version__, "ray_start_s": ray_start_s, "load_before": load_before,
           "load_after": load_after, "where": args.where, "rows": rows}
    stem = Path(args.out)
    write_json(stem.with_suffix(".json"), doc)
    cmd = (f"python benchmarks/bench_cluster.py --files {args.files} --file-points {args.file_points} "
           f"--points {args.points} --workers {workers} --seeds {args.seeds} --repeats {args.repeats}")
    lines = [
        "# Batch compensation on Ray (issue 20)", "",
        f"`{cmd}` on {args.where}. A batch of {args.files} paths of {args.file_points:,} points and one of "
        f"{args.points:,} points (axis points uniform over the strokes), `--method {args.method}`, element-set "
        f"(HTM) field of `random_truth(seed)`; the solve stage of `volcomp compensate` "
        f"(`compensation.batch.solve_batch`, {CHUNK_POINTS:,} points a chunk), timed in one process, the modes "
        f"alternating; median of {args.repeats}. Model residual only (no estimation); every mode's commands equal "
        "the serial run's bit for bit (checked). This process is warmed up first (kernels loaded, "
        "modules imported); the Ray workers are not, which is what \"new actors\" shows.", "",
        f"Load: before `{load_before}`; after `{load_after}`.", "",
        f"Starting the local Ray instance ({workers} CPUs, Ray {ray.__version__}): {ray_start_s:.1f} s (not in "
        "the figures below; `volcomp compensate --cluster ray` without `--address` pays it on every call).", "",
        "| seed | points | serial (s) | threads ×{w} (s) | Ray ×{w}, new actors (s) | Ray ×{w}, warm actors (s) | "
        "serial / Ray warm | serial / threads |".format(w=workers),
        "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        m = r["median_s"]
        lines.append(f"| {r['seed']} | {r['points']:,} | {m['serial']:.1f} | {m['threads']:.1f} | {m['ray (cold)']:.1f} "
                     f"| {m['ray (warm)']:.1f} | {m['serial'] / m['ray (warm)']:.2f}× | {m['serial'] / m['threads']:.2f}× |")
    lines += ["", "Throughput (points per second, serial → threads → Ray new actors → Ray warm): " + "; ".join(
        " → ".join(f"{r['points'] / r['median_s'][k]:,.0f}" for k in ("serial", "threads", "ray (cold)", "ray (warm)"))
        for r in rows) + ".", ""]
    with atomic_write(stem.with_suffix(".md"), "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
