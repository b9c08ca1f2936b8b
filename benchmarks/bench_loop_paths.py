"""Benchmark: the closed loop on the built-in grinder (``volcomp diagnose``: the machine-tool chain loop on the
grinder's chain), per case through the user's CLI path.

Per case (truth family, seed, effect of :data:`loop_cases.EXPECTED`), :func:`loop_cases.run_case` runs sweeps
(2 μm, 21 stations) → simulate (800 checks at 1 μm) → identify → diagnose (60/40 by seq). The truth is used
only to score:

* held-out MEASURED RMS (vector norm, last 40 % of the checks) of the identified stage (the plain baseline)
  and of the kept stage, and its ratio to the noise floor the loop reports (√3·σ̂);
* the effects named (kind and axis word) and whether the first is the injected one;
* TRUE RMS ‖Δe‖ over 5,000 random points (loop_cases' probe points) of the shipped geometry
  (``updated_elements.json``: the kept stage re-estimated on all checks) beside the identified geometry's.

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_loop_paths.py --seeds 0 1 --effect none pitch thermal``
(about 2 CPU min a case on a loaded 2-core machine); prints one JSON row per case and a Markdown table.
"""
from __future__ import annotations

import os

if __name__ == "__main__":
    for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_k, "1")

import argparse
import contextlib
import io
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))


def table(rows: list) -> list[str]:
    """Markdown lines: one row per case."""
    out = ["| case | held-out identified (μm) | held-out kept (μm) | kept / floor | identified geometry TRUE RMS (μm) "
           "| shipped geometry TRUE RMS (μm) | effects named | first right |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['family']} s{r['seed']} {r['effect']} | {r['held_identified_um']:.2f} "
                   f"| {r['held_final_um']:.2f} | {r['held_final_over_floor']:.2f} | {r['sweeps_rms_um']:.2f} "
                   f"| {r['updated_geometry_rms_um']:.2f} | {', '.join(r['effects']) or 'none'} | {r['named_right']} |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", default="independent")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--effect", nargs="+", default=["none", "pitch", "thermal"])
    a = ap.parse_args(argv)
    from loop_cases import run_case
    rows = []
    for seed in a.seeds:
        for eff in a.effect:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                r = run_case(a.family, seed, eff)
            rows.append(r)
            print(json.dumps(r, default=str), flush=True)
    print("\n".join(table(rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
