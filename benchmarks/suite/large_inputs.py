"""Large inputs: a long CSV tool path read by the pyarrow fast path vs the per-row reader, and a long CAM-style
G-code program read and written block-wise.

CSV: ``N`` rows of ``x_mm,z_mm,a_deg`` (random over the default grinder's strokes, 9 significant digits as
``write_csv`` writes them) with a comment header; timed: ``read_table`` plus ``Table.float`` of the three
columns (what ``volcomp compensate`` does with a CSV path), the fast path and the per-row reader (forced by
raising ``FAST_MIN_ROWS`` above the row count), values checked equal bit for bit.

G-code: :func:`gcode_program`, ``N`` CAM-style lines (``N.. G1 X.. Z.. A..`` and modal ``N.. X.. Z.. A..``, 4
decimals, an F word every 1,000 lines, a comment every 5,000; X sweeps the stroke 0.02 mm a line, Z a slow sine,
A 0.05° a line); timed: ``parse_program`` with the default machine's axis words (as ``compensate`` passes them)
and ``render_table`` with stand-in vertices (the compensated values' formatting), after a warm-up on another
file. CPU seconds of this process; the fast path timed after a first read (pyarrow's import) not counted.

    python -m benchmarks.run large_inputs
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

TITLE = "Large inputs: a long CSV tool path and a long CAM-style G-code program read (and written)"
DATA = ("generated: 1,000,000 CSV rows `x_mm,z_mm,a_deg` over the default grinder's strokes (seed 0); a "
        "1,000,000-line CAM-style `N.. G1 X.. Z.. A..` program (`large_inputs.gcode_program`, seed 0)")
COLS = ("x_mm", "z_mm", "a_deg")


def gcode_program(n_lines: int, seed: int = 0) -> str:
    """A CAM-style program of ``n_lines`` lines on the default grinder's X, Z and A (module docstring)."""
    rng = np.random.default_rng(seed)
    n = n_lines - 8
    k = np.arange(n)
    period = 8000
    ph = (k % (2 * period)) / period
    x = 20.0 + 160.0 * np.where(ph < 1, ph, 2 - ph)
    z = 30.0 + 20.0 * np.sin(2 * np.pi * k / 50000.0) + rng.uniform(-0.0005, 0.0005, n)
    a = 0.05 * k
    body = [f"N{10 * (i + 1)} {'G1 ' if i % 2 == 0 else ''}X{xx:.4f} Z{zz:.4f} A{aa:.4f}"
            for i, (xx, zz, aa) in enumerate(zip(x.tolist(), z.tolist(), a.tolist()))]
    for i in range(0, n, 1000):
        body[i] += f" F{200 + (i // 1000) % 7 * 10}."
    for i in range(500, n, 5000):
        body[i] = f"(pass {i // 5000})"
    head = ["%", "O1000 (SCALE BENCH)", "G21 G90 G18 G94", f"G0 X{x[0]:.4f} Z{z[0] + 5:.4f} A0.", "G1 F200."]
    return "\n".join(head + body + ["M5", "M30", "%"]) + "\n"


def csv_read_cpu_s(path: Path, fast: bool) -> tuple:
    """``(CPU s, (N, 3) values)`` of ``read_table`` + ``Table.float`` of :data:`COLS`, fast path or per-row."""
    import errormap.io as eio
    old = eio.FAST_MIN_ROWS
    eio.FAST_MIN_ROWS = 2000 if fast else 10 ** 12
    try:
        c = time.process_time()
        t = eio.read_table(path)
        v = np.stack([t.float(k) for k in COLS], axis=1)
        return time.process_time() - c, v
    finally:
        eio.FAST_MIN_ROWS = old


def gcode_cpu_s(path: Path, warm: Path) -> tuple:
    """``(read CPU s, write CPU s, lines)`` of ``parse_program`` and ``render_table`` (stand-in vertices)."""
    from compensation.gcode import AxisWords, parse_program, render_table
    from errormap.machine import load_machine
    ax = AxisWords.of(load_machine())
    w = parse_program(warm, axis_words=ax)                                  # imports, compiled kernels
    render_table(w, w.table.end[np.flatnonzero(w.table.compensate)], np.ones(int(w.table.compensate.sum()), np.int64))
    c0 = time.process_time()
    prog = parse_program(path, axis_words=ax)
    c1 = time.process_time()
    rows = np.flatnonzero(prog.table.compensate)
    axes = prog.table.end[rows] + 1e-3 * np.sin(np.arange(rows.size * 3, dtype=float)).reshape(-1, 3)
    c2 = time.process_time()
    render_table(prog, axes, np.ones(rows.size, np.int64))
    return c1 - c0, time.process_time() - c2, len(prog.lines)


def run(quick: bool, seed: int) -> dict:
    import errormap.io as eio
    from errormap.machine import load_machine
    from errormap.chain_truth import random_axes
    n = 20_000 if quick else 1_000_000
    with tempfile.TemporaryDirectory() as d:
        csv_path, nc, warm = Path(d) / "path.csv", Path(d) / "scale.nc", Path(d) / "warm.nc"
        axes = random_axes(load_machine(), n, np.random.default_rng(seed))
        eio.write_csv(csv_path, dict(zip(COLS, axes.T)), header_comments=["machine: default grinder"])
        csv_read_cpu_s(csv_path, True)                                      # pyarrow's import (not counted)
        fast_s, vf = csv_read_cpu_s(csv_path, True)
        slow_s, vs = csv_read_cpu_s(csv_path, False)
        nc.write_text(gcode_program(n, seed), encoding="latin-1")
        warm.write_text(gcode_program(2000, seed + 1), encoding="latin-1")
        read_s, write_s, lines = gcode_cpu_s(nc, warm)
    equal = bool(np.array_equal(vf, vs))
    figs = [{"what": f"CSV tool path of {n:,} rows read (pyarrow fast path), CPU", "value": fast_s, "unit": "s",
             "residual": "none", "anchor": "per-row reader, CPU s", "anchor_value": slow_s},
            {"what": f"CAM-style program of {lines:,} lines written (`render_table`), CPU", "value": write_s,
             "unit": "s", "residual": "none", "anchor": "read (`parse_program`), CPU s", "anchor_value": read_s}]
    notes = [f"The two CSV readers' values equal bit for bit: {'yes' if equal else 'NO'}."]
    return {"figures": figs, "notes": notes}
