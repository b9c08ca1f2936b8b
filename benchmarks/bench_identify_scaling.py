"""Cost and agreement of the chain identification (:class:`errormap.identification.ChainIdentification`) on dense
sweeps: one process per run, CPU seconds and peak resident memory of ``fit`` (and of ``smooth_chain`` after it,
the CLI's default), the parameter vector and covariance dumped for an old-vs-new comparison.

Usage: ``OMP_NUM_THREADS=1 python benchmarks/bench_identify_scaling.py run --machine grinder --stations 201 --seed 0
[--gauge station-mean] [--dump out.npz]`` (one run, prints one JSON line); ``compare A.npz B.npz`` (largest
absolute differences of element values, μm or μrad, and covariance, μm² or μrad²). Run a tree's code with
``PYTHONPATH=<tree>``. Data: simulated sweeps (grinder: ``simulate_mt_sweeps`` of ``make_truth(grinder, seed)``, 2 μm
tracker noise; mill-xyz: ``simulate_mt_sweeps`` of ``make_mt_truth(mill, seed)``, noise seed ``seed + 100``).
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time

import numpy as np


def make_sweeps(machine_name: str, stations: int, seed: int):
    """(sweeps, machine-tool chain) of one simulated tracker set-up."""
    from errormap.chain_sweeps import simulate_mt_sweeps, swept_words
    from errormap.machine import load_machine
    from errormap.sweeps import sweeps_from_columns
    if machine_name == "grinder":
        from errormap.truth_families import make_truth
        g = load_machine(None)
        return sweeps_from_columns(simulate_mt_sweeps(make_truth(g, seed), n_stations=stations)), g
    from errormap.chain_truth import make_mt_truth
    mt = load_machine(machine_name)
    cols = simulate_mt_sweeps(make_mt_truth(mt, seed), n_stations=stations, seed=seed + 100)
    return sweeps_from_columns(cols, axes=swept_words(mt)), mt


def run(a) -> None:
    from errormap.identification import ChainIdentification, parameter_vector, smooth_chain
    sweeps, mt = make_sweeps(a.machine, a.stations, a.seed)
    rows = 3 * sum(sweeps[w].command.size for w in sweeps.axes)   # one CSV row per ball
    t0 = time.process_time()
    res = ChainIdentification(gauge=a.gauge).fit(sweeps, mt).result_
    t_fit = time.process_time() - t0
    peak_fit = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.process_time()
    sm = smooth_chain(res, mt)
    t_smooth = time.process_time() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    if a.dump:
        np.savez(a.dump, theta=parameter_vector(res.elements_, res.param_slot, res.param_station), cov=res.cov,
                 theta_s=parameter_vector(sm.elements_, sm.param_slot, sm.param_station), cov_s=sm.cov,
                 condition=res.condition, sigma=res.sigma_um, lev=np.concatenate([v.ravel() for v in res.leverage.values()]))
    print(json.dumps({"machine": a.machine, "stations": a.stations, "rows": rows, "seed": a.seed, "gauge": a.gauge,
                      "unknowns": len(res.param_slot) + 6, "fit_cpu_s": round(t_fit, 2),
                      "fit_peak_gb": round(peak_fit / 1e9, 3), "smooth_cpu_s": round(t_smooth, 2),
                      "peak_gb": round(peak / 1e9, 3), "iterations": res.iterations, "condition": res.condition}))


def compare(a) -> None:
    x, y = np.load(a.old), np.load(a.new)
    out = {k: float(np.abs(x[k] - y[k]).max()) for k in ("theta", "cov", "theta_s", "cov_s", "lev")}
    out["cov_scale"] = float(np.abs(x["cov"]).max())
    out["condition"] = [float(x["condition"]), float(y["condition"])]
    print(json.dumps(out))


def main(argv) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--machine", default="grinder")
    r.add_argument("--stations", type=int, default=21)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--gauge", default="station-mean")
    r.add_argument("--dump", default=None)
    c = sub.add_parser("compare")
    c.add_argument("old")
    c.add_argument("new")
    a = p.parse_args(argv)
    run(a) if a.cmd == "run" else compare(a)


if __name__ == "__main__":
    main(sys.argv[1:])
