"""``volcomp benchmark``: learned vs parametric compensation on the same machines and measurements.

Writes ``DIR/benchmark.json`` (one row per machine, path, condition) and ``DIR/report.html``;
every run is tracked in MLflow under one parent run. See :mod:`compensation.app.workflows.benchmark` and
docs/reference/benchmark.md.
"""
from __future__ import annotations

import sys

from errormap.machine import builtin_machine_path, load_machine



def register(sub):
    p = sub.add_parser(
        "benchmark", help="learned vs parametric path on the same machines and measurements: report.html + benchmark.json",
        description="Run the learned and the parametric compensation paths on the same simulated machines and "
                    "measurements, under varying measurement counts, noise and undeclared effects; report the TRUE "
                    "residual along the test paths and the cost. Default machines: the built-in grinder, hexapod "
                    "and tripod.")
    p.add_argument("--machine", action="append", default=None, metavar="FILE",
                   help="machine file (TOML) or built-in name; repeat for several; default: built-in grinder, "
                        "hexapod, tripod; a machine-tool chain (mill-xyz, five-axis-ac, a file): simulate → sweeps → "
                        "identify → diagnose → exact compensation of its body diagonals (a turning centre such as "
                        "lathe-xzc: lines along X and Z and a face/diameter set at 8 C positions), TRUE residual; a serial arm (ur5, ur10, wam, a file): simulate → calibrate → "
                        "compensate a joint program per arm effect, TRUE landing error of the plain LSQ, geometric "
                        "and kept stages")
    p.add_argument("--out", default="runs/benchmark", metavar="DIR", help="output folder (default runs/benchmark)")
    p.add_argument("--quick", action="store_true",
                   help="reduced conditions and budgets (about a minute; what the test runs)")
    p.add_argument("--tracking-uri", default=None, help="MLflow tracking URI (default: the project's store under runs/)")
    p.add_argument("--no-track", action="store_true", help="do not record MLflow runs")
    p.add_argument("--train-iter", type=int, default=None,
                   help="LM iterations per learned machine-tool condition (default 150; --quick 60): the same networks "
                        "on any machine")
    p.add_argument("--train-s", type=float, default=None,
                   help="also stop each training after this many seconds (off by default: it makes the results depend "
                        "on the machine's load; benchmark.json records the iterations reached)")
    p.add_argument("--checks", type=int, action="append", default=None, metavar="N",
                   help="check measurements of the out-of-catalogue conditions' closed loop (and its hybrid stage); "
                        "repeat for several counts, each a row per effect (default 800, 150 and 1600; --quick 200); "
                        "every machine tool alike")
    p.add_argument("--seed", type=int, default=None, help="seed of measurements and training (default 0)")
    p.add_argument("--truth-seed", type=int, default=None, help="seed of the simulated truth grinder (default 0)")
    p.set_defaults(func=run)


DEFAULT_MACHINES = ("grinder", "hexapod", "tripod")
"""The built-in machines benchmarked without ``--machine``."""


def run(args) -> int:
    from ..workflows.benchmark import BenchmarkSettings, quick_settings, run_benchmark
    s = quick_settings() if args.quick else BenchmarkSettings()
    for k in ("train_iter", "train_s", "seed", "truth_seed"):   # ranges checked before run (validate.py)
        if getattr(args, k) is not None:
            setattr(s, k, getattr(args, k))
    if args.checks:   # each >= 1 and <= MAX_CHECKS (validate.py), checked before run
        s.ooc_checks = tuple(dict.fromkeys(args.checks))
    if args.machine:
        machines = [load_machine(p) for p in args.machine]
    else:
        machines = [load_machine(builtin_machine_path(name)) for name in DEFAULT_MACHINES]
    doc = run_benchmark(machines, args.out, s, tracking_uri=args.tracking_uri, track=not args.no_track)
    from ..reports.benchmark import machine_label, verdict_failed
    avail = [r for r in doc["rows"] if r["available"]]
    failed = [r for r in avail if verdict_failed(r)]
    print(f"{len(avail)} of {len(doc['rows'])} rows measured in {doc['seconds']:.0f} s"
          + (f"; {len(failed)} of them with a failed model verdict (not counted)" if failed else ""), file=sys.stderr)
    print(f"{'machine':8s} {'path':10s} {'true RMS um':>11s} {'max um':>9s}  condition")
    for r in doc["rows"]:
        if r["available"]:
            print(f"{machine_label(r):8s} {r['path']:10s} {r['true_rms_um']:11.3f} {r['true_max_um']:9.3f}  {r['condition']}"
                  + ("  [verdict FAILED: not counted]" if verdict_failed(r) else ""))
        else:
            print(f"{machine_label(r):8s} {r['path']:10s} {'n/a':>11s} {'':9s}  {r['condition']}: {r['not_available']}")
    for k in doc.get("skipped", []):
        print(f"{k['machine']}: skipped: {k['why']}", file=sys.stderr)
    print(f"wrote {doc['paths']['json']}")
    print(f"wrote {doc['paths']['html']}")
    return 0
