"""How long `volcomp demo` takes (goal ≤ 90 s wall on 2 quiet cores): wall and CPU seconds of the whole command.

    python -m benchmarks.run demo            # three demos, one after the other: medians, each run's load beside it
    python -m benchmarks.run demo --quick    # runs no demo (one is ~90 CPU s): the section says so

Each run is a fresh interpreter (``python -m compensation.app.cli demo --out DIR``, DIR and its MLflow store in
a temporary folder), timed from outside: wall by the clock, CPU as the children's user + system seconds (the
demo's worker threads included). The demo's own ``demo.json`` gives each stage's wall / CPU seconds (of its main
process); the median run's stages are the notes. The load average at each start is recorded: on a shared
machine the wall figure is the load's as much as the demo's, the CPU figure much less so.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GOAL_WALL_S = 90.0
"""The product's goal: `volcomp demo` within 90 s wall on 2 quiet cores."""
RUNS_FULL = 3

TITLE = "`volcomp demo` end to end: wall and CPU seconds beside the 90 s goal"
DATA = ("`volcomp demo`'s defaults (simulated grinder seed 0, its feature points, the paper's network trained with "
        "LM, the 2,800-point flute compensated with every method, the report); a fresh interpreter per run, median "
        "of 3 (quick: no run)")


def demo_once(work: Path) -> dict:
    """One ``volcomp demo`` in a fresh interpreter → {wall_s, cpu_s, load_start, stages}."""
    out = work / "demo"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MLFLOW_TRACKING_URI": f"sqlite:///{work / 'mlflow.db'}"}
    load = os.getloadavg()[0]
    t = os.times()
    c0, w0 = t.children_user + t.children_system, time.perf_counter()
    subprocess.run([sys.executable, "-m", "compensation.app.cli", "demo", "--out", str(out)], env=env, check=True,
                   cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - w0
    t = os.times()
    stages = json.loads((out / "demo.json").read_text(encoding="utf-8"))["stages"]
    return {"wall_s": wall, "cpu_s": t.children_user + t.children_system - c0, "load_start": load, "stages": stages}


def run(quick: bool, seed: int) -> dict:
    """Three demos (full) → median wall and CPU seconds beside the goal; quick runs none (figures left empty)."""
    if quick:
        return {"figures": [
            {"what": "`volcomp demo` wall, median", "value": None, "unit": "s", "residual": "none",
             "anchor": "goal on 2 quiet cores", "anchor_value": GOAL_WALL_S},
            {"what": "`volcomp demo` CPU (user + system), median", "value": None, "unit": "s", "residual": "none",
             "anchor": "", "anchor_value": None}],
            "notes": ["Quick: no demo is run (one is ~90 CPU s); the full run gives the figures."]}
    runs = []
    for k in range(RUNS_FULL):
        with tempfile.TemporaryDirectory(prefix=f"demo{k}-") as tmp:
            runs.append(demo_once(Path(tmp)))
    wall = statistics.median(r["wall_s"] for r in runs)
    cpu = statistics.median(r["cpu_s"] for r in runs)
    mid = sorted(runs, key=lambda r: r["wall_s"])[len(runs) // 2]
    stages = ", ".join(f"{k} {v['wall_s']:.1f} / {v['cpu_s']:.1f}" for k, v in mid["stages"].items())
    return {"figures": [
        {"what": f"`volcomp demo` wall, median of {len(runs)}", "value": round(wall, 1), "unit": "s",
         "residual": "none", "anchor": "goal on 2 quiet cores", "anchor_value": GOAL_WALL_S},
        {"what": f"`volcomp demo` CPU (user + system), median of {len(runs)}", "value": round(cpu, 1), "unit": "s",
         "residual": "none", "anchor": "", "anchor_value": None}],
        "notes": ["Runs (wall / CPU s, load average at the start): "
                  + "; ".join(f"{r['wall_s']:.1f} / {r['cpu_s']:.1f} at {r['load_start']:.1f}" for r in runs) + ".",
                  f"Stages of the median run (wall / CPU s of the demo's main process): {stages}."]}
