"""How long `volcomp --help` and `volcomp --version` take (issue 17: target ≤ 1 s).

Runs each command ``--runs`` times in fresh interpreters, interleaved with the same commands of
an optional ``--base`` source tree (e.g. an older commit unpacked with ``git archive``), and
writes the medians to ``benchmarks/cli_startup_results.md``. The machine's load average is
recorded beside: on a shared 2-core machine it dominates the absolute figures, so compare the
two trees only within one run.

    python benchmarks/bench_cli_startup.py --runs 5 [--base /tmp/base]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def time_once(tree: Path, args) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "compensation.app.cli", *args], env=env, check=True, cwd=tree,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--base", type=Path, default=None, help="another source tree to time beside this one")
    ap.add_argument("--base-label", default="base")
    ap.add_argument("--out", type=Path, default=HERE / "cli_startup_results.md")
    a = ap.parse_args()
    trees = {"this tree": ROOT} | ({a.base_label: a.base} if a.base else {})
    times = {(t, c): [] for t in trees for c in ("--help", "--version")}
    load0 = os.getloadavg()[0]
    for _ in range(a.runs):
        for label, tree in trees.items():
            for cmd in ("--help", "--version"):
                if cmd == "--version" and label != "this tree":
                    continue  # older trees have no --version
                times[(label, cmd)].append(time_once(tree, [cmd]))
    load1 = os.getloadavg()[0]
    rows = [f"| `volcomp {c}` | {label} | {statistics.median(v):.2f} | {min(v):.2f} | {max(v):.2f} |"
            for (label, c), v in times.items() if v]
    text = "\n".join([
        "## `volcomp --help` start-up time (issue 17)",
        "",
        f"Median of {a.runs} fresh interpreters each (`python -m compensation.app.cli …`, output discarded), the "
        f"trees interleaved; load average {load0:.1f} → {load1:.1f} on this 2-core machine during the run. "
        "`--help` now imports only the command being run; the light help table imports no numerical library "
        "(numpy, torch, scipy, MLflow, matplotlib; `tests/test_cli_foundation.py` checks it).",
        "",
        "| command | tree | median s | min s | max s |",
        "|---|---|---:|---:|---:|",
        *rows,
        "",
        f"How: `python benchmarks/bench_cli_startup.py --runs {a.runs}"
        + (f" --base <{a.base_label} tree> --base-label '{a.base_label}'`" if a.base else "`"),
        "",
    ])
    a.out.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
