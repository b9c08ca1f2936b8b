"""LinuxCNC per-joint tables of a machine-tool chain averaged over a working region (``export --region``)
against the tables averaged over the whole calibrated volume: the worst and RMS MODEL residual the tables
leave at points inside the region.

What: ``compensation.export.joint_tables_from_model`` with and without ``region``, checked by
``compensation.export.check_export`` (the model machine reached with the tables' commands minus the target).
Data: seeded default-family truths of ``mill-xyz`` (``make_truth(mill-xyz, seed)``: angular errors couple the
axes), 64 lines per joint, 16 samples per node (seed 0), a region 2 % of each stroke wide starting at 40 %,
300 check points in it (seed 3), approach +. Residual kind: MODEL (the truth's own elements are the model).

Run: ``python benchmarks/bench_chain_region.py [--seeds 0 1 2 3 4]``
"""
from __future__ import annotations

import argparse

import numpy as np


def measure(seed: int) -> dict:
    from compensation import export as ex
    from compensation.app.workflows.measurement import make_truth
    from errormap.machine import load_machine
    from errormap.chain_field import ChainField
    m = load_machine("mill-xyz")
    el = make_truth(m, seed).elements
    fld = ChainField(m, el)
    lo, hi = m.stroke_lo, m.stroke_hi
    box = {c: (a + 0.4 * (b - a), a + 0.42 * (b - a)) for c, a, b in zip(m.axis_columns, lo, hi)}
    pts = np.random.default_rng(3).uniform([b[0] for b in box.values()], [b[1] for b in box.values()], (300, 3))
    dirs = np.ones_like(pts)
    out = {}
    for name, region in (("whole volume", None), ("region", box)):
        model = ex.ModelError(m, el, field=fld)
        t = ex.joint_tables_from_model(model, m, 64, samples=16, seed=0, region=region)
        c = ex.check_export(t, model, m, {"p": ex.point_set(m, pts, dirs)})["p"]
        out[name] = c["model"]
    out["none"] = c["baseline_none"]["model"]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    a = ap.parse_args(argv)
    print("| seed | no compensation max (μm) | tables over the volume: max / mean (μm) | tables over the region: max / mean (μm) |")
    print("|---|---|---|---|")
    for s in a.seeds:
        r = measure(s)
        print(f"| {s} | {r['none']['max_um']:.1f} | {r['whole volume']['max_um']:.2f} / {r['whole volume']['mean_um']:.2f} "
              f"| {r['region']['max_um']:.2f} / {r['region']['mean_um']:.2f} |")


if __name__ == "__main__":
    main()
