"""Batch compensation throughput: one process, threads, and a local Ray cluster, side by side.

A batch of paths (axis points uniform over the grinder's strokes, 1 mm / 0.5 mm inside X / Z) on an element-set
(HTM) field of ``make_chain_truth(seed)``, solved through :func:`compensation.batch.solve_batch` (the chunk plan every
run uses) serially, with threads, and on Ray's warm actors (full run, Ray installed); every mode's commands are
checked equal bit for bit to the serial run's. Only the solve stage is timed.

    python -m benchmarks.run cluster
"""
from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from compensation.batch import CHUNK_POINTS, LocalExecutor, solve_batch
from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes
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


TITLE = "Batch compensation: one process, threads and a local Ray cluster, commands bytes-identical"
DATA = ("8 paths of 25,000 points and one of 1,000,000 (quick: 2 × 2,000 and 20,000), axis points uniform over the "
        "grinder's strokes, element-set field of `make_chain_truth(seed)`, `--method exact`, 2 workers; Ray in the full run")


def _time(method, field, machine, paths, seed, ex):
    t = time.perf_counter()
    res = solve_batch(method, field, machine, paths, seed=seed, executor=ex, progress=None)
    return time.perf_counter() - t, np.concatenate([r.commands_mm for r in res])


def run(quick: bool, seed: int, workers: int = 2, method: str = "exact") -> dict:
    """Median-free single timings (one repeat): serial, threads, and (full run, Ray installed) Ray's warm actors."""
    machine = load_machine()
    field = ChainField(machine, make_chain_truth(machine, seed).elements)
    paths = make_batch(machine, 2, 2_000, 20_000, seed) if quick else make_batch(machine, 8, 25_000, 1_000_000, seed)
    n = sum(len(p.axes) for p in paths)
    solve_batch(method, field, machine, make_batch(machine, 1, 100, 100, seed), executor=LocalExecutor(1))  # warm-up
    t_serial, ref = _time(method, field, machine, paths, seed, LocalExecutor(1))
    t_threads, cmds = _time(method, field, machine, paths, seed, LocalExecutor(workers))
    equal = bool(np.array_equal(cmds, ref))
    notes = [f"Load before: `{uptime()}`."]
    figs = [{"what": f"threads ×{workers}: throughput", "value": round(n / t_threads), "unit": "points/s",
             "residual": "none", "anchor": "one process, one thread", "anchor_value": round(n / t_serial)}]
    if not quick:
        try:
            import ray
            from compensation.app.workflows.cluster import RayExecutor
        except ImportError:
            notes.append("Ray is not installed (the `cluster` extra): no Ray figure.")
        else:
            os.environ.setdefault("PYTHONPATH", str(HERE.parents[1]))
            ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
            try:
                with RayExecutor() as ex:
                    _time(method, field, machine, paths, seed, ex)          # new actors
                    t_ray, cmds = _time(method, field, machine, paths, seed, ex)
            finally:
                ray.shutdown()
            equal = equal and bool(np.array_equal(cmds, ref))
            figs.append({"what": f"Ray ×{workers}, warm actors: throughput", "value": round(n / t_ray),
                         "unit": "points/s", "residual": "none", "anchor": "one process, one thread",
                         "anchor_value": round(n / t_serial)})
    figs.append({"what": "every mode's commands equal the serial run's, bit for bit", "value": "yes" if equal else "NO",
                 "unit": "", "residual": "none", "anchor": f"{n:,} points, chunks of {CHUNK_POINTS:,}",
                 "anchor_value": None})
    return {"figures": figs, "notes": notes}
