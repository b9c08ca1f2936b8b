"""How long `volcomp --help` and `volcomp --version` take (target ≤ 1 s): fresh interpreters, medians.

    python -m benchmarks.run cli_startup
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def time_once(tree: Path, args) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "compensation.app.cli", *args], env=env, check=True, cwd=tree,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


TITLE = "`volcomp --help` and `--version` start-up time"
DATA = "fresh interpreters (`python -m compensation.app.cli …`, output discarded), median of 5 runs (quick: 2)"


def run(quick: bool, seed: int) -> dict:
    n = 2 if quick else 5
    load0 = os.getloadavg()[0]
    t = {c: statistics.median(time_once(ROOT, [c]) for _ in range(n)) for c in ("--help", "--version")}
    return {"figures": [{"what": f"`volcomp {c}`, median wall", "value": round(v, 3), "unit": "s", "residual": "none",
                         "anchor": "target", "anchor_value": 1.0} for c, v in t.items()],
            "notes": [f"Load average {load0:.1f} at the start (a shared machine's load dominates the absolute figure)."]}
