"""Benchmark (issue 20): reading a large CSV tool path, the pyarrow fast path of
``errormap.io.read_table`` against the per-row reader, side by side in one run.

The file: ``--rows`` rows of ``x_mm,z_mm,a_deg`` (random over the strokes, 9 significant
digits, as ``write_csv`` writes them) with a comment header. Timed: ``read_table`` plus
``Table.float`` of the three columns (what ``volcomp compensate`` does with a CSV path);
median of ``--repeats`` runs each, alternating. The per-row reader is forced by raising
``FAST_MIN_ROWS`` above the row count. Values are checked equal bit for bit.

    python benchmarks/bench_scale_io.py --rows 1000000 --repeats 3
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np

import errormap.io as eio
from errormap.machine import load_machine
from errormap.simulator import random_axes

COLS = ("x_mm", "z_mm", "a_deg")


def read(path, fast: bool):
    eio.FAST_MIN_ROWS = 2000 if fast else 10**12
    t0 = time.perf_counter()
    t = eio.read_table(path)
    v = np.stack([t.float(c) for c in COLS], axis=1)
    return time.perf_counter() - t0, v


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=1, help="files (one per seed), each timed")
    ap.add_argument("--jobs", type=int, default=1, help="unused: the reads are timed one at a time")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "scale_io_results.md"))
    args = ap.parse_args()
    m = load_machine()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            axes = random_axes(m, args.rows, np.random.default_rng(seed))
            path = os.path.join(tmp, f"path{seed}.csv")
            eio.write_csv(path, dict(zip(COLS, axes.T)), header_comments=["machine: default grinder"])
            size_mb = os.path.getsize(path) / 1e6
            fast, slow = [], []
            for _ in range(args.repeats):
                tf, vf = read(path, True)
                ts, vs = read(path, False)
                fast.append(tf), slow.append(ts)
            assert np.array_equal(vf, vs), "fast and per-row readers disagree"
            rows.append((seed, size_mb, statistics.median(slow), statistics.median(fast), np.array_equal(vf, vs)))
            print(rows[-1])
    lines = ["## CSV read, pyarrow fast path vs per-row reader (issue 20)", "",
             f"`python benchmarks/bench_scale_io.py --rows {args.rows} --repeats {args.repeats} --seeds {args.seeds}` — "
             f"{args.rows:,} rows x_mm,z_mm,a_deg written by write_csv (%.9g); read_table + Table.float of the 3 columns; "
             f"median of {args.repeats} runs each, alternating in one process; {os.cpu_count()} cores shared with other work.", "",
             "| seed | file (MB) | per-row reader (s) | pyarrow path (s) | speed-up | values equal |", "|---|---|---|---|---|---|"]
    for seed, mb, ts, tf, eq in rows:
        lines.append(f"| {seed} | {mb:.0f} | {ts:.2f} | {tf:.2f} | {ts / tf:.1f}× | {'bit for bit' if eq else 'NO'} |")
    text = "\n".join(lines) + "\n"
    print(text)
    with eio.atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
