"""The small run of ``volcomp benchmark`` behind benchmarks/benchmark_results.md's out-of-catalogue section.

The grinder only, ``quick_settings()`` (the (8, 8) tanh network with periodic A, LM 60 iterations,
one flute turn, batched GA on 20 points) with: no catalogue effects; the out-of-catalogue effects
``bump``, ``a_tilt``, ``squareness`` and the same machine without an effect, each with the closed
loop at 800, 150 and 1600 check measurements (``--checks N``, repeatable, replaces them); 300 volume points. No MLflow. Prints the markdown table
(``compensation.app.reports.benchmark.markdown_table``) and the conclusion lines computed from the
rows (``conclusion_lines``); writes ``OUT/benchmark.json`` and ``OUT/report.html``.

    nice -n 10 python benchmarks/bench_benchmark_ooc.py /tmp/bench_ooc [--checks 800 --checks 150 --checks 1600]

``--settings default``: instead, ``volcomp benchmark``'s default settings (the paper's network, LM 150
iterations, the 7-turn flute, batched GA on 100 points, 300 volume points) with only the base condition
(21 stations, 1 μm) and the out-of-catalogue group (its default effects ``bump``, ``a_tilt``, ``squareness``,
``a_lobe_x`` and none; ``--checks`` as above, default 800): the default run's out-of-catalogue rows without
its other conditions.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None):
    from compensation.app.reports.benchmark import conclusion_lines, markdown_table
    from compensation.app.workflows.benchmark import BenchmarkSettings, quick_settings, run_benchmark
    from errormap.machine import load_machine
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="runs/benchmark-ooc")
    ap.add_argument("--checks", type=int, action="append", default=None)
    ap.add_argument("--settings", choices=("quick", "default"), default="quick")
    args = ap.parse_args(argv)
    out = args.out
    if args.settings == "default":
        s = BenchmarkSettings(stations=(21,), noises_um=(1.0,), effects=(), ooc_checks=tuple(args.checks or (800,)))
    else:
        s = quick_settings()
        s.effects = ()
        s.ooc_effects = ("bump", "a_tilt", "squareness")
        s.ooc_checks = tuple(args.checks or (800, 150, 1600))
        s.volume_points = 300
    t0 = time.process_time()
    doc = run_benchmark([load_machine(None, expect_kind="grinder")], out, s, track=False)
    print("cpu_s", time.process_time() - t0, "wall_s", doc["seconds"])
    print("settings", json.dumps({k: v for k, v in s.to_dict().items() if not k.startswith("pkm")}))
    print(markdown_table(doc))
    print("\n".join(conclusion_lines(doc)))


if __name__ == "__main__":
    main()
