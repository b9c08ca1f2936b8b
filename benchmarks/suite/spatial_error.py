"""Benchmark: the exact-HTM spatial error for 1,000,000 points on the default grinder.

Reports the median wall time of 3 runs and the peak memory traced by tracemalloc
(numpy registers its buffers with tracemalloc) for each chunk size, side by side.
Run: python -m benchmarks.run spatial_error
"""
from __future__ import annotations

import statistics
import time
import tracemalloc

import numpy as np

from errormap.chain_field import ChainField
from errormap.machine import load_machine
from errormap.chain_truth import make_chain_truth, random_axes


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


TITLE = "Spatial error of the exact HTM field: throughput and memory"
DATA = "default grinder, `make_chain_truth` seed 0, 1,000,000 random axis points (quick: 100,000), chunks of 200,000"


def run(quick: bool, seed: int) -> dict:
    m = load_machine()
    truth = make_chain_truth(m, seed)
    n = 100_000 if quick else 1_000_000
    axes = random_axes(m, n, np.random.default_rng(seed))
    t_ex, mem = measure(ChainField(m, truth.elements), axes)
    return {"figures": [
        {"what": "exact HTM field, throughput (median of 3)", "value": round(n / t_ex), "unit": "points/s",
         "residual": "none", "anchor": "", "anchor_value": None},
        {"what": "exact HTM field, peak memory (tracemalloc)", "value": round(mem, 1), "unit": "MiB", "residual": "none",
         "anchor": "", "anchor_value": None},
    ], "notes": []}
