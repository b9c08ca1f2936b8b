"""Export benchmark: what each controller table leaves, against the model and against the truth.

    python benchmarks/bench_export.py [--seeds 1] [--jobs 1] [--check-points 2000]
                                      [--tolerances 4,2,1,0.5] [--out benchmarks/export_results.md]

The user's path, per seed s (truth seed 100 + s):
truth = ``random_truth(default grinder, 100 + s, effects=("reversal", "interaction"))`` (8 μm Z
backlash; X positioning that grows with Z: a coupling no per-axis table and no 23-element model
holds); model = ``identify(simulate_mt_sweeps(truth, noise 2 μm, seed s))`` (the 23 elements from
tracker sweeps); diagnosed backlash = ``diagnose`` on 400 simulated check measurements (noise
1 μm, seed s) against that model. Never the truth's own numbers.

For each table the controller is re-simulated (:func:`compensation.export.check_export`) on the
default flute (2,800 points) and ``--check-points`` random points over the volume, and the
**model residual** (against the identified model) and the **true residual** (against the
simulated truth) are reported as max / p95 of the per-point norm, beside the baselines: no
compensation, and the model's own exact compensation (``volcomp compensate --method exact``).
Table size is the bytes of the files written and the number of values.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from compensation import export as ex  # noqa: E402
from errormap.chain_field import ChainField  # noqa: E402
from errormap.uncertainty import smooth_identify  # noqa: E402
from errormap.io import atomic_write, write_json  # noqa: E402
from errormap.machine import load_machine  # noqa: E402
from errormap.simulator import random_truth  # noqa: E402
from errormap.chain_sweeps import simulate_mt_sweeps  # noqa: E402

FLUTE_REGION = {"x_mm": (90.0, 116.0), "z_mm": (0.3, 0.3)}
"""The default flute's axis box (x 90..115.3 mm, z = 0.3 mm): the per-joint fitting region."""


def identify(sweeps, machine, gauge="first-station"):
    """The interpolating identification (the one method, on the grinder's chain) in ``gauge``."""
    return smooth_identify(sweeps, machine, smooth=False, gauge=gauge).raw


def run_seed(seed: int, tolerances, n_volume: int) -> dict:
    m = load_machine()
    truth = random_truth(m, 100 + seed, effects=("reversal", "interaction"))
    el = identify(simulate_mt_sweeps(truth, noise_um=2.0, seed=seed), m).elements_
    model = ex.ModelError(m, el)
    sets = ex.check_sets(m, n_volume, seed)
    tool = ex.truth_tool_points(truth, m)
    cache = {}
    rows = []

    def one(kind, label, mdl, cch, tol=1.0, **options):
        t0 = time.perf_counter()
        table, sizing, chk = ex.build_checked_table(kind, mdl, m, tol, sets, tool, cch, **options)
        with tempfile.TemporaryDirectory() as tmp:
            files = ex.write_table(table, tmp, m, "bench")
            size = ex.table_bytes(files)
        rows.append({"seed": seed, "format": kind, "label": label, "sizing": sizing, "bytes": size,
                     "values": table.n_values(), "check": chk, "seconds": time.perf_counter() - t0})

    for tol in tolerances:
        for fmt in ("grid", "iso-tables"):
            one(fmt, f"tol {tol:g}", model, cache, tol)
    for label, region in (("whole strokes", None), ("flute region", FLUTE_REGION)):
        one("linuxcnc", label, model, cache, region=region, seed=seed)
    # the diagnosed backlash: the user's path (check measurements -> diagnose -> diagnosis effects)
    from errormap.chain_elements import ChainElementSet
    from errormap.diagnosis.chain_loop import MTChecks, closed_loop_chain
    from errormap.diagnosis.loop_model import ChainModelField
    mt = m
    checks = MTChecks.from_columns(mt, truth.check_measurements(n=400, noise_um=1.0, seed=seed))
    with tempfile.TemporaryDirectory() as tmp:
        el_chain = ChainElementSet.load(el.save(Path(tmp) / "el.json"), mt)
    d = closed_loop_chain(mt, el_chain, checks, cov=None)   # the loop on the identified model, no update
    terms = d["_models"]["terms"] if d["kept_stage"].endswith("plus_effects") else []
    with tempfile.TemporaryDirectory() as tmp:
        p = write_json(Path(tmp) / "diagnosis.json", {"effects": [t.to_dict() for t in terms]})
        try:
            back, left = ex.backlash_from_diagnosis(p)
            diag_note = f"diagnosed: {back} (left out: {left})"
        except Exception as exc:  # the refusal itself is a result worth reporting
            back, diag_note = {}, f"diagnosis not usable by a per-joint table: {exc}"
    if back:
        one("linuxcnc", "flute region + diagnosed backlash", ex.ModelError(m, el, reversal={j.upper(): b for j, b in back.items()}), {},
            region=FLUTE_REGION, seed=seed)
    # terms the diagnosis found that depend on the axes only (interaction x*z, periodic, harmonic):
    # a grid can hold the corrected model, per-axis ISO component tables cannot
    axis_only = [t for t in terms if t.kind not in ("thermal", "reversal")]
    if axis_only:
        corrected = ex.ModelError(m, field=ChainModelField(mt, el_chain, axis_only))
        one("grid", f"tol {tolerances[-1]:g}, model + diagnosed axis-only terms", corrected, {}, tolerances[-1])
    return {"seed": seed, "rows": rows, "diagnosis": diag_note,
            "effects": [f"{t.kind}({'*'.join(t.axes)}) on {t.element}" for t in terms]}


def fmt_pair(s):
    return f"{s['max_um']:.3g} / {s['p95_um']:.3g}"


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--check-points", type=int, default=2000)
    ap.add_argument("--tolerances", default="4,2,1,0.5")
    ap.add_argument("--out", default=str(Path(__file__).with_name("export_results.md")))
    args = ap.parse_args(argv)
    tols = [float(t) for t in args.tolerances.split(",")]
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(run_seed, range(args.seeds), [tols] * args.seeds, [args.check_points] * args.seeds))
    else:
        results = [run_seed(s, tols, args.check_points) for s in range(args.seeds)]
    wall = time.perf_counter() - t0
    cmd = "python benchmarks/bench_export.py " + " ".join(argv if argv is not None else sys.argv[1:])
    L = ["## Export: controller tables checked against the model and the truth", "",
         f"`{cmd.strip()}` — {platform.machine()}, {os.cpu_count()} cores shared with other jobs, {wall:.0f} s. "
         "Default grinder; truth `random_truth(100 + seed, effects=(reversal, interaction))` (8 μm Z backlash, "
         "6 μm X-with-Z coupling at the far corner); model = the 23 elements identified from simulated tracker "
         "sweeps (2 μm noise); backlash diagnosed from 400 simulated check measurements. Residuals: per-point "
         "norm, **max / p95 μm**; *model* = against the identified model, *true* = against the simulated truth. "
         f"Flute: the default 7-turn path (2,800 points); volume: {args.check_points} uniform random axis points "
         "(points the model itself cannot compensate, outside the 250 μm ball near the A axis, are excluded; "
         "counts below).", ""]
    for res in results:
        s = res["seed"]
        base = res["rows"][0]["check"]
        L += [f"### seed {s}", "",
              "| baseline | flute model | flute true | volume model | volume true |", "|---|---|---|---|---|",
              f"| no compensation | {fmt_pair(base['flute']['baseline_none']['model'])} | "
              f"{fmt_pair(base['flute']['baseline_none']['true'])} | {fmt_pair(base['volume']['baseline_none']['model'])} | "
              f"{fmt_pair(base['volume']['baseline_none']['true'])} |",
              f"| exact compensation with the model | {fmt_pair(base['flute']['baseline_exact']['model'])} | "
              f"{fmt_pair(base['flute']['baseline_exact']['true'])} | {fmt_pair(base['volume']['baseline_exact']['model'])} | "
              f"{fmt_pair(base['volume']['baseline_exact']['true'])} |", "",
              f"Volume points excluded: {base['volume']['excluded']}. Diagnosis selected: {', '.join(res['effects']) or 'nothing'}; "
              f"{res['diagnosis']}.", "",
              "| format | setting | size (files) | values | sizing | flute model | flute true | volume model | volume true |",
              "|---|---|---|---|---|---|---|---|---|"]
        for r in res["rows"]:
            z = r["sizing"]
            if r["format"] == "grid":
                sz = "nodes {} (spacing {:.3g} mm, {:.3g} mm, {:.3g}°)".format("×".join(map(str, z["counts"])), *z["spacing"])
            elif r["format"] == "iso-tables":
                sz = f"{z['rows_per_axis']} rows per axis"
            else:
                sz = f"{z['points_per_joint']} points per joint"
            c = r["check"]
            L.append(f"| {r['format']} | {r['label']} | {r['bytes'] / 1024:.1f} KiB | {r['values']} | {sz} | "
                     f"{fmt_pair(c['flute']['model'])} | {fmt_pair(c['flute']['true'])} | "
                     f"{fmt_pair(c['volume']['model'])} | {fmt_pair(c['volume']['true'])} |")
        L.append("")
    def pick(res, fmt, label):
        return next((r for r in res["rows"] if r["format"] == fmt and r["label"] == label), None)
    cost, worse, gain, diag = [], [], [], []
    for res in results:
        iso = pick(res, "iso-tables", f"tol {tols[-1]:g}")
        pj = pick(res, "linuxcnc", "flute region")
        ws = pick(res, "linuxcnc", "whole strokes")
        pjd = pick(res, "linuxcnc", "flute region + diagnosed backlash")
        cg = pick(res, "grid", f"tol {tols[-1]:g}, model + diagnosed axis-only terms")
        cost.append((pj["check"]["flute"]["model"]["max_um"], iso["check"]["flute"]["model"]["max_um"],
                     pj["check"]["flute"]["true"]["max_um"], iso["check"]["flute"]["true"]["max_um"]))
        worse.append(ws["check"]["volume"]["model"]["max_um"] > ws["check"]["volume"]["baseline_none"]["model"]["max_um"])
        if pjd:
            diag.append((pj["check"]["flute"]["true"]["max_um"], pjd["check"]["flute"]["true"]["max_um"]))
        if cg:
            gain.append((iso["check"]["flute"]["true"]["max_um"], cg["check"]["flute"]["true"]["max_um"],
                         iso["check"]["volume"]["true"]["max_um"], cg["check"]["volume"]["true"]["max_um"]))
    med = lambda v: float(np.median(v))  # noqa: E731
    c = np.array(cost)
    L += ["Reading it (medians over the seeds):", "",
          f"* **Cost of the coupling terms on the flute (per-joint tables).** A per-joint table fitted over the "
          f"flute's own region leaves {med(c[:, 0]):.3g} μm max model residual on the flute where the ISO component "
          f"tables (tolerance {tols[-1]:g} μm) leave {med(c[:, 1]):.3g} μm; true residual {med(c[:, 2]):.3g} μm vs "
          f"{med(c[:, 3]):.3g} μm. The difference is what one-function-per-joint cannot hold (chiefly the A "
          "correction, which depends on Z and X). Fitted over the whole strokes the per-joint table is worse than "
          f"no compensation on the volume in {sum(worse)} of {len(worse)} seeds; fitted over the flute it is "
          "unusable off the flute (the volume columns).",
          "* **ISO component tables vs the grid.** With a controller that rebuilds the rigid-body model from the "
          "component tables, both meet the tolerance on the model; the ISO tables need orders of magnitude fewer "
          "values (the grid must resolve a rough identified model in all three axes at once). Their true residual "
          "equals the model's own exact compensation's: it is what the identified 23 elements miss."]
    if gain:
        g = np.array(gain)
        L.append(f"* **What per-axis component tables cannot hold.** Terms the diagnosis adds that are not "
                 f"functions of one axis' elements (interaction x·z; periodic or harmonic terms) can go into a grid "
                 f"but not into component tables. Max true residual, ISO tables of the identified model → grid of "
                 f"the model plus the diagnosed axis-only terms: flute {med(g[:, 0]):.3g} → {med(g[:, 1]):.3g} μm, "
                 f"volume {med(g[:, 2]):.3g} → {med(g[:, 3]):.3g} μm (per seed in the tables; that row's model "
                 "residual is against the corrected model). A grid holds such terms only as well as the diagnosis "
                 "found them: terms fitted on 400 random check points need not help on the flute.")
    if diag:
        dd = np.array(diag)
        L.append(f"* **Diagnosed backlash in the LinuxCNC reverse column**: flute true residual "
                 f"{med(dd[:, 0]):.3g} → {med(dd[:, 1]):.3g} μm (the truth's 8 μm Z backlash).")
    L.append("")
    text = "\n".join(L) + "\n"
    with atomic_write(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)
    write_json(Path(args.out).with_suffix(".json"), results)
    print(text)


if __name__ == "__main__":
    main()
