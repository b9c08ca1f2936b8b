"""Compare two sets of ``volcomp benchmark`` runs (one ``benchmark.json`` folder per seed each):
per row, the TRUE residual RMS over the seeds, median (min–max), before and after, as markdown.

Checks that a change that should not alter behaviour leaves the benchmark's figures within the
seed-to-seed spread::

    volcomp benchmark --quick --seed S --no-track --out before_sS   # in the old checkout, S = 0..4
    volcomp benchmark --quick --seed S --no-track --out after_sS    # in the new one
    python tools/compare_benchmark_runs.py --before before_s* --after after_s*
"""
import argparse
import json
from pathlib import Path

import numpy as np


def rows(folder) -> dict:
    doc = json.loads((Path(folder) / "benchmark.json").read_text(encoding="utf-8"))
    return {(r["machine"].split(" (")[0], r["path"], r["condition"]): r for r in doc["rows"] if r.get("available", True)}


def table(before, after) -> str:
    b = [rows(d) for d in before]
    a = [rows(d) for d in after]
    keys = [k for k in b[0] if all(k in x for x in b + a)]
    out = [f"| machine | path | condition | before: RMS μm, median (min–max) over {len(b)} seeds "
           f"| after: RMS μm, median (min–max) over {len(a)} seeds |", "|---|---|---|---|---|"]
    for k in keys:
        vb = np.array([x[k]["true_rms_um"] for x in b])
        va = np.array([x[k]["true_rms_um"] for x in a])
        out.append(f"| {k[0]} | {k[1]} | {k[2]} | {np.median(vb):.2f} ({vb.min():.2f}–{vb.max():.2f}) "
                   f"| {np.median(va):.2f} ({va.min():.2f}–{va.max():.2f}) |")
    return "\n".join(out) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", nargs="+", required=True, help="benchmark output folders of the old checkout")
    ap.add_argument("--after", nargs="+", required=True, help="benchmark output folders of the new checkout")
    args = ap.parse_args(argv)
    print(table(args.before, args.after), end="")


if __name__ == "__main__":
    main()
