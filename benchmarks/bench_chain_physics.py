"""Physics-first training on a machine-tool chain: ``volcomp train --physics none`` vs ``first-order``.

For each machine and truth seed the user's path is run: ``volcomp simulate --machine M --seed S``'s
truth element set (:func:`errormap.chain_truth.make_mt_truth`, saved as ``truth_elements.json``) →
``volcomp featurepoints --machine M --elements truth_elements.json --grid N`` → the fit ``volcomp
train`` runs on those feature points (:func:`training.chain_model.fit_chain_field`: the paper's
10-15-25-15-10 network, LM, seed 0, the iterate best on 5,000 off-grid selection points of the truth
kept), once per ``--physics`` setting. Reported (μm, max = largest |component|), TRUE residuals
(the fitted field minus the hidden truth the feature points were made from):

* ``grid max``      on the feature points;
* ``off-grid max / RMS`` on 10,000 random points over the strokes (``fit_chain_field``'s validation
  points: SeedSequence(0) child 0, never seen in training or selection);
* ``physics alone`` the fitted element set without the network, off the grid (first-order only);
* CPU seconds of the fit (one torch thread, ``time.process_time``; the element-set fit included).

    nice -n 10 python benchmarks/bench_chain_physics.py --markdown /tmp/chain_physics.md --json /tmp/chain_physics.json
    nice -n 10 python benchmarks/bench_chain_physics.py --cases mill-xyz:7 --seeds 1 --iters 20   # smoke
"""
from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def run_case(machine_name: str, grid: int, seed: int, physics: str, iters: int, folder: Path) -> dict:
    """One fit: the truth of ``seed``, its ``grid``-per-axis feature points, ``volcomp train``'s fit."""
    from compensation.app.cli import main
    from errormap.featurepoints import FeaturePoints
    from errormap.io import InputError
    from errormap.machine import load_machine
    from errormap.chain_truth import make_mt_truth
    from errormap.threads import limit_threads
    from training.chain_model import fit_chain_field
    from training.trainers import TrainSettings
    m = load_machine(machine_name)
    truth = folder / f"{machine_name}-{seed}-truth.json"
    fp_csv = folder / f"{machine_name}-{seed}-{grid}.csv"
    if not fp_csv.is_file():
        make_mt_truth(m, seed).elements.save(truth)
        assert main(["featurepoints", "--machine", machine_name, "--elements", str(truth), "--grid", str(grid),
                     "--out", str(fp_csv)]) == 0
    fp = FeaturePoints.load(fp_csv)
    row = {"machine": machine_name, "grid": grid, "n_points": len(fp.axes), "seed": seed, "physics": physics}
    t0 = time.process_time()
    try:
        with limit_threads(1):
            r = fit_chain_field(fp, m, TrainSettings(max_iter=iters, seed=0, physics=physics), quiet=True)
    except InputError as exc:  # the command refuses a network that loses to the OLS baseline: say so
        got = re.search(r"validation RMS ([0-9.e+-]+) μm is not below the plain OLS baseline's ([0-9.e+-]+) μm", str(exc))
        return {**row, "refused": True, "cpu_s": time.process_time() - t0,
                "val_rms_um": float(got[1]), "ols_val_rms_um": float(got[2])}
    cpu = time.process_time() - t0
    mt = r.metrics
    row.update({"refused": False, "iterations": mt["iterations"], "cpu_s": cpu, "grid_max_um": mt["train_max_um"],
           "val_max_um": mt["val_max_um"], "val_rms_um": mt["val_rms_um"],
           "ols_val_max_um": mt["baseline_ols_val_max_um"], "ols_val_rms_um": mt["baseline_ols_val_rms_um"]})
    if physics != "none":
        row.update({"physics_val_max_um": mt["physics_val_max_um"], "physics_alone_kept": mt["physics_alone_kept"],
                    "physics_stations": r.params["physics_stations"]})
    return row


def markdown(rows, args) -> str:
    out = ["| machine | grid | seed | --physics | grid max μm | off-grid max μm | off-grid RMS μm | physics alone "
           "off-grid max μm | CPU s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["refused"]:
            out.append(f"| {r['machine']} | {r['grid']} ({r['n_points']} pts) | {r['seed']} | {r['physics']} | refused: "
                       f"off-grid RMS {r['val_rms_um']:.2f} μm not below OLS {r['ols_val_rms_um']:.2f} μm | | | | "
                       f"{r['cpu_s']:.1f} |")
            continue
        alone = f"{r['physics_val_max_um']:.3f}" + (" (kept)" if r["physics_alone_kept"] else "") \
            if r["physics"] != "none" else "—"
        out.append(f"| {r['machine']} | {r['grid']} ({r['n_points']} pts) | {r['seed']} | {r['physics']} | "
                   f"{r['grid_max_um']:.3g} | {r['val_max_um']:.3f} | {r['val_rms_um']:.3f} | {alone} | {r['cpu_s']:.1f} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="mill-xyz:7,mill-xyz:11,five-axis-ac:4", help="MACHINE:GRID, comma-separated")
    ap.add_argument("--seeds", default="1,2", help="truth seeds (volcomp simulate --seed)")
    ap.add_argument("--iters", type=int, default=200, help="LM iterations (volcomp train --max-iter)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--markdown", default=None)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-chain-physics-") as tmp:
        for case in args.cases.split(","):
            name, grid = case.split(":")
            for seed in (int(s) for s in args.seeds.split(",")):
                for physics in ("none", "first-order"):
                    rows.append(run_case(name, int(grid), seed, physics, args.iters, Path(tmp)))
                    print(json.dumps(rows[-1]), flush=True)
    md = markdown(rows, args)
    print(md)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    if args.markdown:
        Path(args.markdown).write_text(md, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
