"""TRUE error of a machine-tool chain's identification, interpolating vs smoothed by the grinder's UBRE smoother
(:func:`errormap.identification.smooth_chain`): per machine and truth seed, simulated sweeps at 2 μm (noise seed
100 + seed), the RMS of (identified − hidden truth) over every function slot's station values (μm and μrad
mixed) and over 2,000 tool points (μm).

    PYTHONPATH=. python benchmarks/bench_chain_smoothing.py [--seeds 5]
"""
from __future__ import annotations

import argparse

import numpy as np

from compensation.export import volume_points as check_points
from errormap.machine import load_machine
from errormap.identification import ChainIdentification, smooth_chain, station_error_rms
from errormap.chain_truth import make_mt_truth
from errormap.chain_sweeps import simulate_mt_sweeps, swept_words
from errormap.sweeps import sweeps_from_columns

MACHINES = ("mill-xyz", "five-axis-ac")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    n = ap.parse_args().seeds
    print("| machine | seed | elements raw → smoothed | tool point raw → smoothed (μm) |")
    print("|---|---|---|---|")
    for name in MACHINES:
        m = load_machine(name)
        for seed in range(n):
            truth = make_mt_truth(m, seed)
            sw = sweeps_from_columns(simulate_mt_sweeps(truth, noise_um=2.0, seed=100 + seed), source="<sim>",
                                     axes=swept_words(m))
            raw = ChainIdentification().fit(sw, m).result_
            sm = smooth_chain(raw, m)
            q = check_points(raw.elements_, 2000, 7)
            t = m.spatial_error(q, truth.elements.values(q))
            tp = [np.sqrt(np.mean((m.spatial_error(q, e.values(q)) - t) ** 2)) for e in (raw.elements_, sm.elements_)]
            ee = [station_error_rms(m, e, truth.elements) for e in (raw.elements_, sm.elements_)]
            print(f"| {name} | {seed} | {ee[0]:.2f} → {ee[1]:.2f} | {tp[0]:.2f} → {tp[1]:.2f} |")


if __name__ == "__main__":
    main()
