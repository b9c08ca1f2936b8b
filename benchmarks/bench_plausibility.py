"""Plausibility gates on check deviations: margins on correct data, and the mistakes caught.

For each machine-tool chain and seed: a truth (independent family), its tracker sweeps (2 μm noise),
the identification, and check measurements (1 μm noise). Against the IDENTIFIED model's prediction:

* the unit gate's margin: the smallest measured / predicted RMS ratio of a column (the gate refuses below
  1 / ``UNIT_RATIO`` = 0.02) — on the correct file, and whether the file with its deviations in mm is refused;
* the axis gate's margin: the best other column order's squared residual / the given order's (the gate
  refuses below ``AXIS_FIT_RATIO`` = 0.25) — on the correct file, and whether dx/dy exchanged is refused.

    python benchmarks/bench_plausibility.py --machines mill-xyz five-axis-ac lathe-xzc --seeds 3
"""
from __future__ import annotations

import argparse
import itertools

import numpy as np

from errormap.diagnosis.plausibility import deviation_axis_mistake, deviation_unit_mistake
from errormap.machine import load_machine
from errormap.chain_field import ChainField
from errormap.identification import ChainIdentification
from errormap.chain_truth import make_mt_truth
from errormap.chain_sweeps import simulate_mt_sweeps, swept_words
from errormap.sweeps import sweeps_from_columns

ERR = ("dx_um", "dy_um", "dz_um")


def row(name: str, seed: int, n_checks: int) -> dict:
    m = load_machine(name)
    t = make_mt_truth(m, seed, family="independent")
    sw = sweeps_from_columns(simulate_mt_sweeps(t, noise_um=2.0, seed=seed + 100), axes=swept_words(m))
    el = ChainIdentification().fit(sw, m).result_.elements_
    ck = t.check_measurements(n_checks, noise_um=1.0, seed=seed + 200)
    meas = np.stack([ck[c] for c in ERR], 1)
    pred = ChainField(m, el).predict(np.stack([ck[c] for c in m.axis_columns], 1))
    rms = lambda a: np.sqrt(np.mean(a ** 2, axis=0))  # noqa: E731
    given = np.sum((meas - pred) ** 2)
    other = min(np.sum((meas[:, p] - pred) ** 2) for p in itertools.permutations(range(3)) if p != (0, 1, 2))
    return {"machine": name, "seed": seed, "unit_margin": float((rms(meas) / rms(pred)).min()),
            "axis_margin": float(other / given),
            "false_alarm": deviation_unit_mistake(meas, pred, 1.0) is not None
            or deviation_axis_mistake(meas, pred) is not None,
            "mm_refused": deviation_unit_mistake(meas / 1000, pred, 1.0) is not None,
            "swap_refused": deviation_axis_mistake(meas[:, [1, 0, 2]], pred) is not None}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", nargs="+", default=["mill-xyz", "five-axis-ac", "lathe-xzc"])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--checks", type=int, default=200)
    a = ap.parse_args(argv)
    print("| machine | seed | min measured/predicted RMS (refused < 0.02) | best other order / given (refused < 0.25) "
          "| false alarm | mm refused | dx/dy swap refused |")
    print("|---|---|---|---|---|---|---|")
    for name in a.machines:
        for seed in range(a.seeds):
            r = row(name, seed, a.checks)
            print(f"| {name} | {seed} | {r['unit_margin']:.3f} | {r['axis_margin']:.1f} | {r['false_alarm']} | "
                  f"{r['mm_refused']} | {r['swap_refused']} |", flush=True)


if __name__ == "__main__":
    main()
