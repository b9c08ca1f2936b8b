"""The grinder's seeded truths (errormap.chain_truth) against a checkout that had errormap/simulator.py.

For each seed, family (default, independent) and effect set (none; all eleven simulator effects), the truth's
spatial error at 10,000 seeded points under seeded conditions and its 400 check measurements, from this
checkout (``make_mt_truth``) and from BASELINE (``errormap.truth_families.make_truth``, run in a subprocess
with BASELINE on PYTHONPATH); prints the largest difference (μm; 0 = the same floats).

    PYTHONPATH=. OMP_NUM_THREADS=1 python benchmarks/bench_grinder_truth.py --baseline-root MAIN_BEFORE \
        --seeds 0,1,3,4,11,100
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

EFFECTS = ("thermal", "reversal", "pitch", "worm", "interaction", "bump", "a_tilt", "squareness",
           "squareness_xz", "a_lobe_x", "xz_saddle")
N_POINTS = 10_000


def draw(make_truth, seeds) -> dict:
    """``{case: array}``: spatial errors (N_POINTS, 3) and check columns of every case."""
    from errormap.machine import load_machine
    from errormap.seeds import spawn_seeds
    m = load_machine(None)
    rng = np.random.default_rng(99)
    pts = m.stroke_lo + (m.stroke_hi - m.stroke_lo) * rng.random((N_POINTS, 3))
    dirs = {f"dir_{w}": rng.choice([-1.0, 1.0], N_POINTS) for w in "xza"}
    cond = {"temp_c": 20 + 4 * rng.random(N_POINTS), **dirs}
    out = {}
    for fam in ("default", "independent"):
        for seed in seeds:
            for eff in ((), EFFECTS):
                t = make_truth(m, seed, effects=eff, family=fam)
                case = f"{fam}-{seed}-{len(eff)}"
                out[case + "-field"] = t.spatial_error(pts, **cond)
                ck = t.check_measurements(n=400, seed=spawn_seeds(seed, 1)[0])
                out[case + "-checks"] = np.stack([np.asarray(ck[k], float) for k in sorted(ck)])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-root", help="checkout with errormap/simulator.py (omit: this checkout only)")
    ap.add_argument("--seeds", default="0,1,3,4,11,100")
    ap.add_argument("--save", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.save:   # the baseline's side, in its own process
        from errormap.truth_families import make_truth
        np.savez(args.save, **draw(make_truth, seeds))
        return 0
    from errormap.chain_truth import make_mt_truth
    ours = draw(make_mt_truth, seeds)
    if not args.baseline_root:
        print(f"{len(ours)} arrays drawn; no baseline given")
        return 0
    with tempfile.TemporaryDirectory() as td:
        path = Path(td) / "baseline.npz"
        env = {**os.environ, "PYTHONPATH": str(Path(args.baseline_root).resolve())}
        cmd = [sys.executable, str(Path(__file__).resolve()), "--seeds", args.seeds, "--save", str(path)]
        subprocess.run(cmd, check=True, env=env, cwd=args.baseline_root)
        with np.load(path) as base:
            worst = {k: float(np.abs(ours[k] - base[k]).max()) for k in ours}
    for k, v in worst.items():
        print(f"{k:28s} max |difference| {v:.3g}")
    print(f"largest: {max(worst.values()):.3g} (field um / check columns)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
