"""Benchmark: the exact-HTM spatial error for 1,000,000 points on the default grinder.

Reports the median wall time of 3 runs and the peak memory traced by tracemalloc
(numpy registers its buffers with tracemalloc) for each chunk size, side by side.
Run: python benchmarks/bench_spatial_error.py [--points N] [--out benchmarks/foundation_results.md]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
import tracemalloc

import numpy as np

from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.simulator import random_axes, random_truth


def measure(field, axes, repeats=3):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        field.predict(axes)
        times.append(time.perf_counter() - t0)
    tracemalloc.start()
    field.predict(axes)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return statistics.median(times), peak / 2**20


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "foundation_results.md"))
    args = ap.parse_args()
    m = load_machine()
    truth = random_truth(m, 0)
    axes = random_axes(m, args.points, np.random.default_rng(0))
    rows = []
    for chunk in (50_000, 200_000, 1_000_000):
        field = ChainField(m, truth.elements, chunk=chunk)
        t, mem = measure(field, axes)
        rows.append((f"exact, chunk {chunk:,}", t, mem))
        print(rows[-1])
    lines = ["## Spatial error, 1,000,000 points (issue 2)", "",
             f"`python benchmarks/bench_spatial_error.py` — default grinder, truth seed 0, {args.points:,} random points "
             f"over the strokes, 23 elements by B-spline, {os.cpu_count()} cores; median of 3 runs; peak memory by tracemalloc "
             "(input array of 24 MB excluded).", "",
             "| model | time (s) | peak memory (MiB) | points/s |", "|---|---|---|---|"]
    for name, t, mem in rows:
        lines.append(f"| {name} | {t:.2f} | {mem:.0f} | {args.points / t:,.0f} |")
    with open(args.out, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
