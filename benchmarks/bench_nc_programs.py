"""Programs as shops write them: subprograms/macros and turning mode (BENCHMARKS.md, last section).

    PYTHONPATH=. python benchmarks/bench_nc_programs.py            # all three parts
    PYTHONPATH=. python benchmarks/bench_nc_programs.py --parse-only   # the 1M-line reading time alone

1. Counts over benchmarks/nc_styles/ (programs written for this bench in the styles of LinuxCNC's public
   nc_files and of Fanuc shop programs, not copies): read by ``parse_program`` with ``mill-xyz``'s words:
   accepted, refused (the reason), crashed (any exception other than InputError).
2. Turning on ``lathe-xzc``: a seeded ±10 μm truth element set (seed 301), the model = truth + 0.3 μm noise
   (seed 302, as tests/test_turning.py), ``compensate --method exact --truth`` of tests/test_turning.py's
   turning program; TRUE residual (radial/axial deviation from the programmed surface of revolution, mean
   over a spindle turn) before/after, and the out-of-roundness X and Z cannot correct.
3. CPU time to read a 1,000,000-line three-axis program without marks (run once with PYTHONPATH=. and
   once with the main checkout to compare).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent / "tests"))


def counts():
    from compensation.gcode import AxisWords, parse_program
    from errormap.io import InputError
    from errormap.machine import load_machine
    ax = AxisWords.of(load_machine("mill-xyz"))
    out, reasons = Counter(), Counter()
    for p in sorted((ROOT / "nc_styles").iterdir()):
        try:
            prog = parse_program(p, axis_words=ax)
            out["accepted"] += 1
            print(f"  {p.name}: accepted, {len(prog.moves)} moves"
                  + (f", {len(prog.expanded.origin)} executed lines" if prog.expanded is not None else ""))
        except InputError as exc:
            out["refused"] += 1
            why = str(exc).split(": ", 2)[-1]
            reasons[why.split(":")[0][:60]] += 1
            print(f"  {p.name}: refused: {str(exc).split(p.name + ': ', 1)[-1][:150]}")
        except Exception as exc:  # noqa: BLE001 - counted, that is the point
            out["crashed"] += 1
            print(f"  {p.name}: CRASHED {type(exc).__name__}: {exc}")
    print(f"programs: {sum(out.values())}; " + ", ".join(f"{k} {v}" for k, v in sorted(out.items())))


def turning():
    from compensation.app.cli import main
    from errormap.machine import load_machine
    from errormap.chain_elements import ChainElementSet
    from test_turning import ESTIMATE_NOISE_UM, TURNING, _noisy  # noqa: F401 - the test's program and noise
    mt = load_machine("lathe-xzc")
    truth = ChainElementSet.random(mt, 301, 10.0, 11)
    rng = np.random.default_rng(302)
    est = ChainElementSet(mt, truth.stations, {k: _noisy(v, rng) for k, v in truth.functions.items()},
                          {k: v + rng.normal(0.0, ESTIMATE_NOISE_UM) for k, v in truth.constants.items()})
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        tp, ep, prog = truth.save(d / "truth.json"), est.save(d / "est.json"), d / "turn.nc"
        prog.write_text(TURNING)
        for name, model in (("model (truth + 0.3 um noise)", ep), ("oracle (the truth)", tp)):
            assert main(["compensate", str(prog), "--machine", "lathe-xzc", "--model", str(model), "--method", "exact",
                         "--truth", str(tp), "--out", str(d / name[:5]), "--work-offsets", "machine"]) == 0
            e = json.loads((d / name[:5] / "compensate_summary.json").read_text())["files"][0]["turning"]
            print(f"turning, {name}: {e['points']} points, TRUE before max {e['true_uncompensated']['max_um']:.3f} "
                  f"rms {e['true_uncompensated']['rms_um']:.3f} um -> after max {e['true']['max_um']:.4g} rms "
                  f"{e['true']['rms_um']:.4g} um; out-of-roundness (not correctable) max "
                  f"{e['true_roundness_max_um']:.3f} um")


def parse_time(n=1_000_000):
    from compensation.gcode import AxisWords, parse_program
    from errormap.machine import load_machine
    ax = AxisWords.of(load_machine("mill-xyz"))
    v = np.random.default_rng(0).uniform(0, 100, (n, 3))
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "big.nc"
        p.write_text("G21 G90\n(pocket)\n" + "".join(f"G1 X{a:.4f} Y{b:.4f} Z{c:.4f} F500\n" for a, b, c in v) + "M30\n")
        parse_program(p, axis_words=ax)  # compile / warm
        best = min(_cpu(parse_program, p, ax) for _ in range(3))
    print(f"reading {n:,} lines without marks: {best:.2f} s CPU (best of 3)")


def _cpu(f, p, ax):
    t = time.process_time()
    f(p, axis_words=ax)
    return time.process_time() - t


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--parse-only", action="store_true")
    a = ap.parse_args()
    if not a.parse_only:
        counts()
        turning()
    parse_time()
