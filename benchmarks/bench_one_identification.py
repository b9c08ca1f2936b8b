"""One identification for every machine tool: TRUE errors of the product's identification on the grinder and on
two chains, per truth seed (2 μm tracker noise, 21 stations).

* grinder: the closed-loop benchmark's no-effect sweeps (``bench_sweeps_band.loop_sweeps('default', seed)``),
  :func:`errormap.uncertainty.smooth_identify` (``volcomp identify``'s defaults); 5,000 probe points.
* mill-xyz, five-axis-ac: ``make_mt_truth(m, seed)``, sweeps at noise seed 100 + seed, the chain identification
  interpolating (raw) and smoothed; 2,000 check points.

Figures, all TRUE (against the hidden truth): tool point ‖Δe‖ RMS / max (μm); element error RMS / max over every
function element's station values against the truth expressed in the identification's gauge (the identification of
the truth's noise-free sweeps, as the identify --truth overlay; μm and μrad mixed); the fraction of point
components whose true error lies inside the reported 95 % band.

    PYTHONPATH=. python benchmarks/bench_one_identification.py [--seeds 5] [--which grinder,chains]
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

Z95 = 1.959963984540054


def _stats(d) -> tuple:
    n = np.linalg.norm(np.atleast_2d(d), axis=1)
    return float(np.sqrt(np.mean(n**2))), float(n.max())


def _el_stats(el, truth, names) -> tuple:
    d = np.concatenate([np.asarray(el.functions[k]) - np.asarray(truth.functions[k]) for k in names])
    return float(np.sqrt(np.mean(d**2))), float(np.abs(d).max())


def grinder_case(seed: int) -> dict:
    from bench_sweeps_band import N_PROBE, _sweeps
    from compensation.app.cli import main
    from compensation.app.workflows.measurement import truth_in_gauge
    from errormap.elements import FUNCTION_ELEMENTS
    from errormap.chain_field import ChainField
    from errormap.machine import load_machine
    from errormap.seeds import spawn_seeds
    from errormap.simulator import random_axes
    from errormap.truth_families import make_truth
    from errormap.uncertainty import prediction_sd, smooth_identify
    import tempfile
    m = load_machine()
    noise_ss, probe_ss = spawn_seeds(seed, 2)
    truth = make_truth(m, seed, family="default")
    P = random_axes(m, N_PROBE, np.random.default_rng(probe_ss))
    et = ChainField(m, truth.elements).predict(P)
    with tempfile.TemporaryDirectory() as td:
        sw = _sweeps(main, Path(td), "default", seed, int(noise_ss.generate_state(1)[0]))
    sm = smooth_identify(sw, m)
    e = ChainField(m, sm.elements_).predict(P) - et
    sd = prediction_sd(m, sm.elements_, sm.covariance_.cov, P)
    tg = truth_in_gauge(m, truth.elements, "station-mean", sm.elements_.stations)
    return {"tp": _stats(e), "el": _el_stats(sm.elements_, tg, FUNCTION_ELEMENTS),
            "cover": float(np.mean(np.abs(e) <= Z95 * sd))}


def chain_case(name: str, seed: int) -> dict:
    from compensation.app.workflows.measurement import chain_band_sd
    from compensation.export import volume_points as check_points
    from errormap.machine import load_machine
    from errormap.chain_truth import make_mt_truth
    from errormap.chain_sweeps import simulate_mt_sweeps, swept_words
    from errormap.sweeps import sweeps_from_columns
    from errormap.identification import ChainIdentification, smooth_chain
    m = load_machine(name)
    truth = make_mt_truth(m, seed)
    sw = sweeps_from_columns(simulate_mt_sweeps(truth, noise_um=2.0, seed=100 + seed), source="<sim>",
                             axes=swept_words(m))
    free = sweeps_from_columns(simulate_mt_sweeps(truth, noise_um=0.0, seed=0), source="<sim>", axes=swept_words(m))
    gauges = ("first-station", "station-mean") if "gauge" in ChainIdentification.__init__.__code__.co_varnames \
        else ("first-station",)
    out = {}
    for g in gauges:
        kw = {"gauge": g} if g != "first-station" else {}
        tg = ChainIdentification(**kw).fit(free, m).elements_
        raw = ChainIdentification(**kw).fit(sw, m).result_
        q = check_points(raw.elements_, 2000, 7)
        t = m.spatial_error(q, truth.elements.values(q))
        names = list(m.function_slots)
        for label, res in (("raw", raw), ("smoothed", smooth_chain(raw, m))):
            e = m.spatial_error(q, res.elements_.values(q)) - t
            sd = chain_band_sd(m, res.elements_, (res.param_slot, res.param_station, res.cov), q)
            out[f"{g} {label}"] = {"tp": _stats(e), "el": _el_stats(res.elements_, tg, names),
                                   "cover": float(np.mean(np.abs(e) <= Z95 * sd))}
    return out


def _row(label, seed, r) -> str:
    return (f"| {label} | {seed} | {r['tp'][0]:.2f} / {r['tp'][1]:.2f} | {r['el'][0]:.2f} / {r['el'][1]:.2f} | "
            f"{r['cover']:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--which", default="grinder,chains")
    a = ap.parse_args()
    print("| machine / method | seed | tool point RMS / max (μm) | elements RMS / max | 95 % band coverage |")
    print("|---|---|---|---|---|")
    if "grinder" in a.which:
        for s in range(a.seeds):
            print(_row("grinder", s, grinder_case(s)), flush=True)
    if "chains" in a.which:
        for name in ("mill-xyz", "five-axis-ac"):
            for s in range(a.seeds):
                r = chain_case(name, s)
                for k, v in r.items():
                    print(_row(f"{name} {k}", s, v), flush=True)


if __name__ == "__main__":
    main()
